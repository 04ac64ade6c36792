"""The panel every widget of :mod:`sin3dm_lite.show.widgets` is (a row of controls above an ``Output`` area), and
the controls several panels share."""

from __future__ import annotations

import traceback
from collections.abc import Callable
from contextlib import contextmanager

import ipywidgets as widgets
from IPython.display import clear_output, display
from matplotlib.figure import Figure


class Explorer(widgets.VBox):
    """Controls + output; ``render(**values) -> Figure`` (a library figure function) runs whenever a control changes.

    ``on_change(name, value)``, when given, runs first (under :meth:`hold`), e.g. to adjust another control's
    range, so the figure is redrawn once per user action.
    """

    def __init__(
        self,
        controls: dict[str, widgets.ValueWidget],
        render: Callable[..., Figure],
        on_change: Callable[[str, object], None] | None = None,
        title: str | None = None,
    ):
        self.controls = dict(controls)
        self.output = widgets.Output()
        self.last_figure: Figure | None = None
        self.last_error: str | None = None
        self._render = render
        self._on_change = on_change
        self._held = False
        header = [widgets.HTML(f"<b>{title}</b>")] if title else []
        super().__init__(children=[*header, widgets.HBox(list(self.controls.values())), self.output])
        for name, control in self.controls.items():
            control.observe(lambda change, name=name: self._changed(name, change["new"]), names="value")
        self.refresh()

    def values(self) -> dict:
        return {name: c.value for name, c in self.controls.items()}

    def figure(self) -> Figure:
        """The figure for the current control values (exceptions propagate)."""
        return self._render(**self.values())

    @contextmanager
    def hold(self):
        """Change several controls without redrawing after each one."""
        held, self._held = self._held, True
        try:
            yield
        finally:
            self._held = held

    def refresh(self) -> Figure | None:
        """Redraw the output; a failing render shows its traceback there (and in ``last_error``)."""
        with self.output:
            clear_output(wait=True)
            try:
                fig = self.figure()
            except Exception:  # show it: ipywidgets would otherwise swallow it
                self.last_error = traceback.format_exc()
                print(self.last_error)
                return None
            self.last_error = None
            self.last_figure = fig
            display(fig)
            return fig

    def _changed(self, name: str, value) -> None:
        if self._held:
            return
        if self._on_change is not None:
            with self.hold():
                self._on_change(name, value)
        self.refresh()


def float_slider(value, lo, hi, step, description, readout_format=".2f", kind=widgets.FloatSlider, **kwargs):
    """A slider (``kind``: a float or float-range one) that redraws when released."""
    kwargs.update(description=description, continuous_update=False, readout_format=readout_format)
    return kind(value=value, min=lo, max=hi, step=step, **kwargs)


def show_in(output: widgets.Output, *items) -> None:
    """Replace what ``output`` shows by ``items``."""
    with output:
        clear_output(wait=True)
        for item in items:
            display(item)


__all__ = ["Explorer"]
