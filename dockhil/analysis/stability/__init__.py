"""What `dockhil stability` computes beyond contact/ (report.py), the text it prints (text.py) and its map
(plot.py)."""
