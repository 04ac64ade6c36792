"""Show: matplotlib figures (``viz``), k3d viewers (``viewer``, with ``camera``), standalone HTML pages (``pages``),
ipywidgets panels (``widgets``)."""
