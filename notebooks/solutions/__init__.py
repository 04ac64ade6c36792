"""Solutions to the notebooks' exercises, one module each; ``sin3dm_lite.teach.exercises`` (also ``from sin3dm_lite import check_…``) has the checks.

Try the exercise first: each notebook imports its solution right after the stub you fill in, so that the
notebook runs as it is; delete that import line and your own function is the one checked.
"""
