"""Checks and conversions of a user's real images and painted labels.

Every function here turns bad input into a ``ValueError`` that names the problem and
the fix, before any numerical code sees it.
"""

from __future__ import annotations

import numpy as np

from napari_symbac.fit.preflight import refuse_non_finite

__all__ = ["CLASS_NAMES", "CLASS_VALUES", "as_image_stack", "as_label_stack", "as_single_image"]

#: Values of the painted classes in a single labels layer.
CLASS_VALUES: dict[str, int] = {"cell": 1, "media": 2, "device": 3}
#: Class names by value.
CLASS_NAMES: dict[int, str] = {value: name for name, value in CLASS_VALUES.items()}


def as_image_stack(image: np.ndarray, *, name: str = "image") -> np.ndarray:
    """Return ``image`` as a float64 ``(T, Y, X)`` stack, rejecting what cannot be used.

    Accepts a 2D image or a ``(T, Y, X)`` stack of any integer or float dtype.

    Raises
    ------
    ValueError
        For RGB(A) images, other dimensionalities, NaN/inf, booleans, complex
        values, or a constant image.
    """
    array = np.asarray(image)
    if array.dtype == bool or np.issubdtype(array.dtype, np.complexfloating):
        raise ValueError(
            f"{name} has dtype {array.dtype}; expected a grey-level image of integer or float "
            "values"
        )
    if not np.issubdtype(array.dtype, np.number):
        raise ValueError(f"{name} has non-numeric dtype {array.dtype}")
    if array.ndim in (3, 4) and array.shape[-1] in (3, 4) and array.shape[-2] > 4:
        raise ValueError(
            f"{name} looks like an RGB(A) image (shape {array.shape}); use one grey channel, "
            "e.g. image[..., 0], or skimage.color.rgb2gray(image)"
        )
    if array.ndim == 2:
        array = array[None]
    if array.ndim != 3:
        raise ValueError(
            f"{name} must be 2D (Y, X) or a time series (T, Y, X), got {array.ndim} dimensions "
            f"with shape {array.shape}; select one channel / z-plane first"
        )
    if min(array.shape[1:]) < 8:
        raise ValueError(f"{name} of shape {array.shape[1:]} is too small: need at least 8 x 8")
    array = array.astype(np.float64)
    refuse_non_finite(array, name)
    if array.max() == array.min():
        raise ValueError(f"{name} is constant (every pixel is {array.flat[0]:g}): nothing to fit")
    return array


def as_label_stack(
    labels: np.ndarray, image_shape: tuple[int, int, int], *, required: tuple[str, ...] = ()
) -> np.ndarray:
    """Return painted class labels as an int ``(T, Y, X)`` stack matching the image.

    Parameters
    ----------
    labels
        Class map with values from :data:`CLASS_VALUES` (0 = unpainted); 2D labels are
        used for every frame of a time series.
    image_shape
        Shape of the ``(T, Y, X)`` image the labels belong to.
    required
        Class names that must be painted somewhere.
    """
    array = np.asarray(labels)
    if not (np.issubdtype(array.dtype, np.integer) or array.dtype == bool):
        if np.issubdtype(array.dtype, np.floating) and np.all(np.mod(array, 1) == 0):
            array = array.astype(np.int64)
        else:
            raise ValueError(f"labels must hold integer class values, got dtype {array.dtype}")
    if array.ndim == 2:
        array = np.broadcast_to(array, (image_shape[0], *array.shape))
    if array.shape != tuple(image_shape):
        raise ValueError(
            f"labels of shape {np.shape(labels)} do not match the image of shape "
            f"{tuple(image_shape) if image_shape[0] > 1 else tuple(image_shape[1:])}: paint "
            "the labels on the same image"
        )
    unknown = sorted(set(np.unique(array).tolist()) - {0, *CLASS_NAMES})
    if unknown:
        raise ValueError(
            f"labels contain unknown class value(s) {unknown}; use "
            + ", ".join(f"{value} = {name}" for value, name in CLASS_NAMES.items())
        )
    missing = [name for name in required if not np.any(array == CLASS_VALUES[name])]
    if missing:
        raise ValueError(
            f"labels are missing the class(es) {', '.join(missing)}: paint a few pixels of "
            f"each ({', '.join(f'{CLASS_VALUES[n]} = {n}' for n in missing)})"
        )
    return array.astype(np.int64, copy=False)


def as_single_image(image: np.ndarray, *, name: str = "image") -> np.ndarray:
    """Return one 2D float64 frame, rejecting a stack where a single frame is expected.

    A ``(1, Y, X)`` stack is accepted and squeezed. Everything :func:`as_image_stack`
    rejects is rejected here too.

    Raises
    ------
    ValueError
        For a time series of more than one frame (pick one: ``image[t]``), and for
        everything :func:`as_image_stack` rejects.
    """
    stack = as_image_stack(image, name=name)
    if stack.shape[0] != 1:
        raise ValueError(
            f"{name} is a stack of {stack.shape[0]} frames (shape {stack.shape}) but a single "
            f"frame is expected here: pick one, e.g. {name}[0]"
        )
    return stack[0]
