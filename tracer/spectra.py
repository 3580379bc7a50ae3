"""Spectra as Mitsuba's RGB variants see them: `<spectrum>` values turned into linear sRGB.

A spectrum given as wavelength:value pairs is integrated against the CIE 1931 colour matching functions
(the 2-degree observer, tabulated every 5 nm from 360 to 830 nm and interpolated linearly), sampled at
1000 evenly spaced wavelengths over that range, and converted from XYZ to linear sRGB (Rec. 709
primaries). A reflectance is weighted by the D65 illuminant (a flat reflectance of 1 becomes white) and
clamped to [0, 1]; an emitter's radiance is not weighted (a flat spectrum becomes D65-relative purple)
and only its negative components are clamped to 0. A single value is a flat spectrum: a reflectance
keeps it as a grey, an emitter gets value * xyz_to_srgb(1, 1, 1).
"""
from __future__ import annotations

import numpy as np

CIE_MIN, CIE_MAX, CIE_SAMPLES = 360.0, 830.0, 95
STEPS = 1000
CIE_Y_NORMALIZATION = 1.0 / 106.7502593994140625     # a flat spectrum of 1 has luminance 1
D65_NORMALIZATION = 1.0 / 98.99741751876255          # D65 has luminance 1

# CIE 1931 2-degree colour matching functions and the CIE D65 illuminant, 360-830 nm in 5 nm steps.
_CIE_X = (
    0.0001299, 0.0002321, 0.0004149, 0.0007416, 0.001368, 0.002236, 0.004243, 0.00765, 0.01431, 0.02319,
    0.04351, 0.07763, 0.13438, 0.21477, 0.2839, 0.3285, 0.34828, 0.34806, 0.3362, 0.3187, 0.2908, 0.2511,
    0.19536, 0.1421, 0.09564, 0.05795001, 0.03201, 0.0147, 0.0049, 0.0024, 0.0093, 0.0291, 0.06327, 0.1096,
    0.1655, 0.2257499, 0.2904, 0.3597, 0.4334499, 0.5120501, 0.5945, 0.6784, 0.7621, 0.8425, 0.9163, 0.9786,
    1.0263, 1.0567, 1.0622, 1.0456, 1.0026, 0.9384, 0.8544499, 0.7514, 0.6424, 0.5419, 0.4479, 0.3608, 0.2835,
    0.2187, 0.1649, 0.1212, 0.0874, 0.0636, 0.04677, 0.0329, 0.0227, 0.01584, 0.01135916, 0.008110916,
    0.005790346, 0.004109457, 0.002899327, 0.00204919, 0.001439971, 0.0009999493, 0.0006900786, 0.0004760213,
    0.0003323011, 0.0002348261, 0.0001661505, 0.000117413, 8.307527e-05, 5.870652e-05, 4.150994e-05,
    2.935326e-05, 2.067383e-05, 1.455977e-05, 1.025398e-05, 7.221456e-06, 5.085868e-06, 3.581652e-06,
    2.522525e-06, 1.776509e-06, 1.251141e-06,
)
_CIE_Y = (
    3.917e-06, 6.965e-06, 1.239e-05, 2.202e-05, 3.9e-05, 6.4e-05, 0.00012, 0.000217, 0.000396, 0.00064,
    0.00121, 0.00218, 0.004, 0.0073, 0.0116, 0.01684, 0.023, 0.0298, 0.038, 0.048, 0.06, 0.0739, 0.09098,
    0.1126, 0.13902, 0.1693, 0.20802, 0.2586, 0.323, 0.4073, 0.503, 0.6082, 0.71, 0.7932, 0.862, 0.9148501,
    0.954, 0.9803, 0.9949501, 1, 0.995, 0.9786, 0.952, 0.9154, 0.87, 0.8163, 0.757, 0.6949, 0.631, 0.5668,
    0.503, 0.4412, 0.381, 0.321, 0.265, 0.217, 0.175, 0.1382, 0.107, 0.0816, 0.061, 0.04458, 0.032, 0.0232,
    0.017, 0.01192, 0.00821, 0.005723, 0.004102, 0.002929, 0.002091, 0.001484, 0.001047, 0.00074, 0.00052,
    0.0003611, 0.0002492, 0.0001719, 0.00012, 8.48e-05, 6e-05, 4.24e-05, 3e-05, 2.12e-05, 1.499e-05, 1.06e-05,
    7.4657e-06, 5.2578e-06, 3.7029e-06, 2.6078e-06, 1.8366e-06, 1.2934e-06, 9.1093e-07, 6.4153e-07, 4.5181e-07,
)
_CIE_Z = (
    0.0006061, 0.001086, 0.001946, 0.003486, 0.006450001, 0.01054999, 0.02005001, 0.03621, 0.06785001, 0.1102,
    0.2074, 0.3713, 0.6456, 1.03905, 1.3856, 1.62296, 1.74706, 1.7826, 1.77211, 1.7441, 1.6692, 1.5281,
    1.28764, 1.0419, 0.8129501, 0.6162, 0.46518, 0.3533, 0.272, 0.2123, 0.1582, 0.1117, 0.07824999, 0.05725001,
    0.04216, 0.02984, 0.0203, 0.0134, 0.008749999, 0.005749999, 0.0039, 0.002749999, 0.0021, 0.0018,
    0.001650001, 0.0014, 0.0011, 0.001, 0.0008, 0.0006, 0.00034, 0.00024, 0.00019, 0.0001, 4.999999e-05, 3e-05,
    2e-05, 1e-05, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0,
    0, 0, 0, 0, 0, 0,
)
_D65 = (
    46.6383, 49.3637, 52.0891, 51.0323, 49.9755, 52.3118, 54.6482, 68.7015, 82.7549, 87.1204, 91.486, 92.4589,
    93.4318, 90.057, 86.6823, 95.7736, 104.865, 110.936, 117.008, 117.41, 117.812, 116.336, 114.861, 115.392,
    115.923, 112.367, 108.811, 109.082, 109.354, 108.578, 107.802, 106.296, 104.79, 106.239, 107.689, 106.047,
    104.405, 104.225, 104.046, 102.023, 100.0, 98.1671, 96.3342, 96.0611, 95.788, 92.2368, 88.6856, 89.3459,
    90.0062, 89.8026, 89.5991, 88.6489, 87.6987, 85.4936, 83.2886, 83.4939, 83.6992, 81.863, 80.0268, 80.1207,
    80.2146, 81.2462, 82.2778, 80.281, 78.2842, 74.0027, 69.7213, 70.6652, 71.6091, 72.979, 74.349, 67.9765,
    61.604, 65.7448, 69.8856, 72.4863, 75.087, 69.3398, 63.5927, 55.0054, 46.4182, 56.6118, 66.8054, 65.0941,
    63.3828, 63.8434, 64.304, 61.8779, 59.4519, 55.7054, 51.959, 54.6998, 57.4406, 58.8765, 60.3125,
)

XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535],
                        [-0.969256, 1.875991, 0.041556],
                        [0.055648, -0.204043, 1.057311]])


class SpectrumError(ValueError):
    pass


def _tabulated(table: tuple, wavelengths: np.ndarray) -> np.ndarray:
    """A 5 nm table interpolated linearly at `wavelengths` (0 outside 360-830 nm)."""
    values = np.asarray(table, np.float32).astype(float)
    t = (wavelengths - CIE_MIN) * ((CIE_SAMPLES - 1) / (CIE_MAX - CIE_MIN))
    i0 = np.clip(t.astype(np.int64), 0, CIE_SAMPLES - 2)
    w1 = t - i0
    out = (1.0 - w1) * values[i0] + w1 * values[i0 + 1]
    return np.where((wavelengths >= CIE_MIN) & (wavelengths <= CIE_MAX), out, 0.0)


def cie1931_xyz(wavelengths: np.ndarray) -> np.ndarray:
    """The colour matching functions at `wavelengths` (nm), shape (n, 3)."""
    w = np.asarray(wavelengths, float)
    return np.stack([_tabulated(t, w) for t in (_CIE_X, _CIE_Y, _CIE_Z)], axis=-1)


def d65(wavelengths: np.ndarray) -> np.ndarray:
    """The D65 illuminant at `wavelengths` (nm), normalised to luminance 1."""
    return _tabulated(_D65, np.asarray(wavelengths, float)) * D65_NORMALIZATION


def _float(text: str) -> float:
    """A number as Mitsuba parses one (Python's float also reads 1_0 as 10)."""
    if "_" in text:
        raise ValueError(text)
    return float(text)


def parse_pairs(text: str) -> tuple[np.ndarray, np.ndarray]:
    """"400:0.5, 500:0.7, ..." as wavelengths and values; wavelengths must increase."""
    try:
        pairs = [item.split(":") for item in text.replace(",", " ").split()]
        wavelengths = np.array([_float(w) for w, _ in pairs])
        values = np.array([_float(v) for _, v in pairs])
    except ValueError:
        raise SpectrumError(f"'{text[:40]}' is not a list of wavelength:value pairs") from None
    if len(wavelengths) < 2:
        raise SpectrumError("a spectrum needs at least two wavelength:value pairs")
    if not (np.all(np.isfinite(wavelengths)) and np.all(np.isfinite(values))):
        raise SpectrumError("a spectrum's wavelengths and values must be finite")
    if np.any(np.diff(wavelengths) <= 0):
        raise SpectrumError("a spectrum's wavelengths must increase")
    return wavelengths, values


def list_to_srgb(wavelengths: np.ndarray, values: np.ndarray, bounded: bool, illuminant: bool) -> np.ndarray:
    """Linear sRGB of a piecewise-linear spectrum (Mitsuba's spectrum_list_to_srgb): `illuminant` weights
    it by D65 (reflectances), `bounded` clamps to [0, 1] (else only negatives are clamped)."""
    w = CIE_MIN + np.arange(STEPS) / (STEPS - 1) * (CIE_MAX - CIE_MIN)
    w = w[(w >= wavelengths[0]) & (w <= wavelengths[-1])]
    i = np.clip(np.searchsorted(wavelengths, w, side="right") - 1, 0, len(wavelengths) - 2)
    w0, w1, v0, v1 = wavelengths[i], wavelengths[i + 1], values[i], values[i + 1]
    v = ((w - w1) * v0 + (w0 - w) * v1) / (w0 - w1)
    if illuminant:
        v = v * d65(w)
    xyz = (cie1931_xyz(w) * v[:, None]).sum(axis=0) * ((CIE_MAX - CIE_MIN) * CIE_Y_NORMALIZATION / STEPS)
    rgb = XYZ_TO_SRGB @ xyz
    return np.clip(rgb, 0.0, 1.0) if bounded else np.maximum(rgb, 0.0)


def to_rgb(text: str, emitter: bool, unbounded: bool = False) -> np.ndarray:
    """A `<spectrum value="...">` as the RGB Mitsuba's RGB variants use: a reflectance unless `emitter`;
    an `unbounded` quantity (a conductor's eta or k) is D65-weighted like a reflectance but not clamped
    above 1."""
    if ":" not in text:
        try:
            value = _float(text)
        except ValueError:
            raise SpectrumError(f"'{text}' is neither a number nor wavelength:value pairs") from None
        if not np.isfinite(value):
            raise SpectrumError(f"'{text}' is not a finite number")
        return value * XYZ_TO_SRGB.sum(axis=1) if emitter else np.full(3, value)
    wavelengths, values = parse_pairs(text)
    return list_to_srgb(wavelengths, values, bounded=not (emitter or unbounded), illuminant=not emitter)


def rgb(value) -> tuple[float, float, float]:
    """An RGB value (an array of three) as the tuple of floats scene descriptions hold."""
    return tuple(float(x) for x in value)
