"""Show: matplotlib figures (``viz``), k3d viewers (``viewer``, with ``camera``), standalone HTML pages (``pages``),
ipywidgets panels (``widgets``: the panel ``explorer``, the sampling stage's in ``sampling_widgets``)."""
