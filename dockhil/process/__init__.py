"""The old name of dockhil.runtime.process, kept for `python -m dockhil.process` (see __main__.py)."""
