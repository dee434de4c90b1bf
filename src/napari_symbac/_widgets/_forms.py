"""A magicgui form for any frozen settings dataclass.

Fields become spin boxes, check boxes and combo boxes with their units in the label;
nested settings become titled sub-forms. :attr:`SettingsForm.value` builds (and so
validates) the dataclass; invalid input raises the dataclass' own ``ValueError``.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from typing import Any, Literal

from magicgui.widgets import (
    CheckBox,
    ComboBox,
    Container,
    FloatSpinBox,
    Label,
    LineEdit,
    SpinBox,
    TextEdit,
    Widget,
)

__all__ = [
    "SettingsForm",
    "fill_height",
    "hide_label",
    "message_label",
    "parameter_docs",
    "report_box",
]

_UNIT_SUFFIXES = {
    "_um2": "um²",
    "_um": "um",
    "_min": "min",
    "_mm": "mm",
    "_px": "px",
    "_adu": "ADU",
    "_e": "e⁻",
    "_per_min": "1/min",
    "_adu_per_e": "ADU/e⁻",
}


#: Readable labels for field names that say little on their own (units where they have one).
_READABLE = {
    "n_frames": "frames",
    "n_founders": "founder cells",
    "interdivision_time_var_min2": "interdivision time variance (min²)",
    "septum_sd": "septum position sd (fraction)",
    "angle_jitter_rad": "angle jitter (rad)",
    "phys_iters": "physics iterations per frame",
    "lysis_p": "lysis probability per frame",
    "do_transformation": "bend cells (eq. 1)",
    "save_dir": "save folder",
    "upsample": "render upsampling (x camera)",
    "cell_intensity": "cell intensity (ADU)",
    "media_intensity": "media intensity (ADU)",
    "device_intensity": "device intensity (ADU)",
    "psf_offset": "PSF offset (weight)",
    "texture_amplitude": "agar texture amplitude",
    "texture_scale_um": "agar texture scale (µm; 0 = random)",
    "cell_brightness_cv": "cell brightness CV",
    "cell_brightness_max_gain": "brightest cell (× mean cell; 0 = unbounded)",
    "envelope_stain_fraction": "stain in the envelope (fraction, fluorescence)",
    "depth_layers": "depth slabs (eq. 16, fluorescence; 0 = 2-D)",
    "debris_density_per_100um2": "debris particles per 100 µm²",
    "debris_brightness": "debris brightness (× cell column)",
    "debris_brightness_cv": "debris brightness CV",
    "debris_diameter_cv": "debris diameter CV",
    "numerical_aperture": "numerical aperture (NA)",
    "refractive_index": "immersion refractive index",
    "bit_depth": "bit depth (bits)",
    "magnification": "magnification (x)",
    "dxf_path": "DXF file",
    "dxf_layer": "DXF layer",
}


def _label(name: str) -> str:
    if name in _READABLE:
        return _READABLE[name]
    for suffix, unit in sorted(_UNIT_SUFFIXES.items(), key=lambda kv: -len(kv[0])):
        if name.endswith(suffix):
            return f"{name[: -len(suffix)].replace('_', ' ')} ({unit})"
    return name.replace("_", " ")


def _float_step(value: float) -> float:
    magnitude = abs(value) if value else 1.0
    step = 10 ** (int(f"{magnitude:e}".split("e")[1]) - 1)
    return float(step)


def _is_text(annotation: Any) -> bool:
    args = set(typing.get_args(annotation)) - {type(None)}
    return annotation is str or args == {str}


def message_label(name: str, label: str | None = None) -> Label:
    """A label for a message of any length: its words wrap at the dock's width, and it
    never widens the dock (a word-wrapped QLabel's minimum width grows with its text:
    an Auto-fit report took the dock from 508 to 674 px of a 1366 px screen)."""
    from qtpy.QtWidgets import QSizePolicy

    widget = Label(name=name, value="", label=label)
    widget.native.setWordWrap(True)
    widget.native.setMinimumWidth(1)
    # magicgui's labels are Fixed: wrapped, the text then got the width Qt guesses for
    # it (61 of a 471 px row: a word or two a line); it takes the row's width instead
    widget.native.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Preferred)
    return widget


def report_box(name: str = "report") -> TextEdit:
    """A read-only box for a plain-text report, its lines kept whole (scrolled sideways,
    never wrapped: its tables stay columns) and never widening the dock. Add it to its
    container, then :func:`hide_label` and :func:`fill_height` it."""
    widget = TextEdit(name=name, label=name, value="")
    widget.read_only = True
    widget.native.setMinimumWidth(0)
    widget.native.setLineWrapMode(widget.native.LineWrapMode.NoWrap)
    return widget


def fill_height(container: Container, widget: Widget) -> None:
    """Let ``widget`` (a report box) take the height ``container`` has spare.

    Its row of ``container`` gets a stretch, so a docked step keeps no empty room below
    it (``workflow._rows_at_the_top`` then adds none): found as a user, the Diagnose
    report was 11 lines tall above half a dock of nothing, its text scrolled.
    """
    from qtpy.QtWidgets import QSizePolicy

    policy = widget.native.sizePolicy()
    policy.setVerticalPolicy(QSizePolicy.Policy.Expanding)
    widget.native.setSizePolicy(policy)
    row = getattr(widget, "_labeled_widget", lambda: None)() or widget
    container.native.layout().setStretchFactor(row.native, 1)


def hide_label(widget: Widget) -> None:
    """Hide the label column of ``widget`` inside its labelled container (a sub-form or a
    heading needs none; the column would take the dock's width)."""
    labeled = getattr(widget, "_labeled_widget", lambda: None)()
    if labeled is not None:
        labeled._label_widget.visible = False


def parameter_docs(cls: type) -> dict[str, str]:
    """``{field: description}`` from the numpy-style "Parameters" section of ``cls``."""
    lines = (cls.__doc__ or "").splitlines()
    docs: dict[str, list[str]] = {}
    inside, current, indent = False, [], None
    for line in lines:
        text = line.strip()
        if text == "Parameters":
            inside = True
            continue
        if not inside or set(text) == {"-"}:
            continue
        if text and indent is None:
            indent = len(line) - len(line.lstrip())
        if text and len(line) - len(line.lstrip()) == indent:
            if text.endswith(":") or text in ("Returns", "Attributes", "Raises", "Notes"):
                break
            current = [name.strip() for name in text.split(":")[0].split(",")]
            for name in current:
                docs[name] = []
        elif text:
            for name in current:
                docs[name].append(text)
        elif indent is not None and not current:
            break
    return {name: " ".join(words).replace("``", "") for name, words in docs.items() if words}


def _field_widget(name: str, annotation: Any, value: Any) -> Widget | None:
    """An editor for one field, or ``None`` for values a form cannot edit (tuples)."""
    label = _label(name)
    origin = typing.get_origin(annotation)
    if dataclasses.is_dataclass(annotation):
        # titled inside, no label column: nested labels then stay readable in a narrow dock
        return SettingsForm(type(value), value=value, name=name, label="", title=label)
    if origin is Literal:
        return ComboBox(
            name=name, label=label, choices=list(typing.get_args(annotation)), value=value
        )
    if annotation is bool:
        return CheckBox(name=name, label=label, value=value)
    if annotation is int:
        return SpinBox(name=name, label=label, value=value, min=-(2**31), max=2**31 - 1)
    if annotation is float:
        box = FloatSpinBox(name=name, label=label, min=-1e9, max=1e9, step=_float_step(value))
        # four significant digits of the default's size: Qt rounds every value to the
        # box's decimals (found as a user: a pixel size of 0.0745 um became 0.074)
        magnitude = math.floor(math.log10(abs(value))) if value else 0
        box.native.setDecimals(max(box.native.decimals(), 3 - magnitude))
        box.value = value
        return box
    if _is_text(annotation):  # text and optional text (paths): empty -> None
        return LineEdit(name=name, label=label, value="" if value is None else str(value))
    return None


class SettingsForm(Container):
    """Editable form of a settings dataclass.

    Parameters
    ----------
    cls
        The frozen settings dataclass.
    value
        Initial settings; defaults to ``cls()``.
    choices
        Optional ``{field: [choices]}`` for string fields with a fixed set of values.
    title
        Heading shown as the form's first row (sub-forms of nested settings).
    """

    def __init__(
        self,
        cls: type,
        value: Any | None = None,
        *,
        choices: dict[str, list[str]] | None = None,
        title: str | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(**kwargs)
        if title:
            heading = Label(name="_title", value=f"<b>{title}</b>")
            self.append(heading)
            hide_label(heading)
        self._cls = cls
        self._fixed: dict[str, Any] = {}  # fields kept as they are (no editor)
        value = cls() if value is None else value
        hints = typing.get_type_hints(cls)
        choices = choices or {}
        tooltips = parameter_docs(cls)
        for field in dataclasses.fields(cls):
            current = getattr(value, field.name)
            if field.name in choices:
                widget = ComboBox(
                    name=field.name,
                    label=_label(field.name),
                    choices=choices[field.name],
                    value=current,
                )
            else:
                widget = _field_widget(field.name, hints[field.name], current)
            if widget is None:
                self._fixed[field.name] = current
            else:
                widget.tooltip = tooltips.get(field.name) or _label(field.name)
                self.append(widget)
                if isinstance(widget, SettingsForm):
                    hide_label(widget)
        self._remember_exact(value)

    def _remember_exact(self, settings: Any) -> None:
        # Spin boxes round what they show; a field the user did not touch keeps its
        # exact value (shown value -> exact value).
        self._exact = {
            widget.name: (widget.value, getattr(settings, widget.name))
            for widget in self
            if isinstance(widget, FloatSpinBox)
        }

    def _editors(self) -> list[Widget]:
        """The field editors (not the title)."""
        return [widget for widget in self if not isinstance(widget, Label)]

    @property
    def value(self) -> Any:
        """The settings currently in the form (validated on construction)."""
        kwargs = dict(self._fixed)
        for widget in self._editors():
            raw = widget.value
            if isinstance(widget, LineEdit):
                raw = raw or None
            shown, exact = self._exact.get(widget.name, (None, None))
            kwargs[widget.name] = exact if shown is not None and raw == shown else raw
        return self._cls(**kwargs)

    @value.setter
    def value(self, settings: Any) -> None:
        self._fixed = {name: getattr(settings, name) for name in self._fixed}
        for widget in self._editors():
            current = getattr(settings, widget.name)
            widget.value = (
                ("" if current is None else str(current))
                if isinstance(widget, LineEdit)
                else current
            )
