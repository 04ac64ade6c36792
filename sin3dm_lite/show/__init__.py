"""Show: matplotlib figures (``viz``), k3d viewers and HTML pages (``viewer``), ipywidgets panels (``widgets``)."""
