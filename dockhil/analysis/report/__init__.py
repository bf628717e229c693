"""The report (`dockhil report`): what it computes (compute.py), its cases (case.py, cases.py, graph_cases.py,
loop_cases.py), the work-precision runs (precision.py, ivp.py), the graph's cost (graph.py), and how it is
written out (markdown.py, plots.py)."""
