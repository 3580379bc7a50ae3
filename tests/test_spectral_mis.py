"""volpathmis's spectral MIS (tracer.integrators.volpath, `_throughput`) on a chromatic slab against its
closed form, and its noise against volpath's.

The slab of tests/test_media.py (thickness 1, albedo 0, a constant environment of radiance 1 behind) with
scale x sigma_t = (10, 2, 10) / 2: its transmittance T = exp(-(5, 1, 5)). A path passes the slab with the
probability T_c of its channel c. volpath weighs channel i by T_i / T_c, so G takes exp(4) = 55 from the
paths that R or B let through: its variance per path is 1/3 T_G + 2/3 exp(3) - T_G^2 = 13.3. Spectral MIS
weighs it by T_i / mean_k T_k (one-sample balance heuristic over the channels), a variance of
T_G^2 / mean(T) - T_G^2 = 0.93: about 14 times less. The mean is checked as tests/test_media.py checks it
(z-test at |z| < 4.5, false-positive rate 1e-5 a channel); the variance ratio, measured on 16 x 16 pixels
of 64 paths (its relative standard error below 20%), must exceed 4.

A wrong spectral MIS is shown to fail: each channel divided by its own distance density (beta_i / r_i, for
beta_i / mean(r)) gives mean(T) in every channel, far outside; dividing by the chosen channel's density
alone is volpath's estimator, which the variance check rejects."""
from __future__ import annotations

import dataclasses

import drjit as dr
import numpy as np
import pytest

import tracer
from tracer.integrators import volpath
from tracer.rendering import render

from .test_media import ENVIRONMENT, assert_close, slab_scene

SIGMA = np.array([5.0, 1.0, 5.0])
MEDIUM = '<rgb name="sigma_t" value="1, 0.2, 1"/><rgb name="albedo" value="0"/><float name="scale" value="5"/>'


def _slab(tmp_path, spectral_mis: bool):
    scene = tracer.load_scene(slab_scene(tmp_path, MEDIUM, ENVIRONMENT))
    return dataclasses.replace(scene, integrator="volpathmis" if spectral_mis else "volpath", spectral_mis=spectral_mis)


def _pixel_variance(image: np.ndarray) -> np.ndarray:
    return image.reshape(-1, 3).astype(np.float64).var(0, ddof=1)


def test_spectral_mis_is_unbiased_and_lowers_green_variance(tmp_path):
    mis = render(_slab(tmp_path, True)).image
    plain = render(_slab(tmp_path, False)).image
    expected = np.exp(-SIGMA)
    assert_close(mis, expected, wrong=np.full(3, expected.mean()))
    assert_close(plain, expected)
    ratio = _pixel_variance(plain) / _pixel_variance(mis)
    assert ratio[1] > 4, ratio


def test_a_wrong_spectral_mis_fails(tmp_path, monkeypatch):
    """Each channel divided by its own distance density instead of the channels' mean: mean(T) everywhere."""
    monkeypatch.setattr(volpath, "_throughput", _own_density)
    image = render(_slab(tmp_path, True)).image
    with pytest.raises(AssertionError):
        assert_close(image, np.exp(-SIGMA))
    assert_close(image, np.full(3, np.exp(-SIGMA).mean()))


def _own_density(beta, r, mis: bool):
    return dr.select(r > 0, beta / r, 0.0) if mis else beta


def test_volpaths_noise_fails_the_variance_check(tmp_path, monkeypatch):
    """Dividing by the chosen channel's density alone (volpath's weights under the name volpathmis)."""
    monkeypatch.setattr(volpath, "_throughput", lambda beta, r, mis: beta)
    ratio = _pixel_variance(render(_slab(tmp_path, False)).image) / _pixel_variance(render(_slab(tmp_path, True)).image)
    assert ratio[1] < 4, ratio
