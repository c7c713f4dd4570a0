"""Log-Gabor filter bank in the Fourier domain and Kovesi's phase congruency.

A bank of ``n_scales * n_orient`` log-Gabor filters is built once per (padded) image size and
cached. Each filter is one-sided in frequency (its angular spread covers less than a half plane),
so one inverse FFT of ``F(image) * filter`` gives the even (real part) and the odd (imaginary part)
quadrature responses at once. All filters are applied in one batched ``scipy.fft.ifft2`` call.

Orientations: filter ``o`` responds to intensity variation along the direction at angle
``o * pi / n_orient`` from the +x axis (the column axis) towards -y (upwards on screen, Kovesi's
convention); it is the *normal* of the edges it finds. Only the index ring matters to the
descriptors: rotating the image by ``pi / n_orient`` shifts the index of the strongest filter by one.

Phase congruency follows Kovesi [1]_ [2]_ (``phasecong3``): energy along each orientation, less a
noise threshold estimated from the smallest scale's amplitude (Rayleigh model), weighted by the
spread of frequencies present, divided by the summed amplitude. Its moments over orientations give
an edge measure (maximum moment) and a corner measure (minimum moment).

References
----------
.. [1] P. Kovesi, "Image Features from Phase Congruency", Videre 1(3), 1999.
.. [2] P. Kovesi, "Phase Congruency Detects Corners and Edges", DICTA 2003.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.fft

__all__ = ["LogGaborBank", "PhaseCongruency", "log_gabor_bank", "phase_congruency"]

_EPS = 1e-4  # Kovesi's epsilon against division by zero (images scaled to [0, 1])


@dataclass(frozen=True, eq=False)
class LogGaborBank:
    """Log-Gabor transfer functions for one image size.

    Attributes
    ----------
    filters : (n_scales * n_orient, H, W) float32 ndarray
        Real transfer function of filter ``o * n_scales + s`` (orientation-major), in unshifted
        FFT layout.
    n_scales, n_orient : int
    angles : (n_orient,) float64 ndarray
        Filter orientations in radians, ``o * pi / n_orient``.
    """

    filters: np.ndarray
    n_scales: int
    n_orient: int
    angles: np.ndarray


@lru_cache(maxsize=8)
def log_gabor_bank(shape: tuple[int, int], *, n_scales: int = 4, n_orient: int = 6,
                   min_wavelength: float = 3.0, mult: float = 2.1,
                   sigma_onf: float = 0.55) -> LogGaborBank:
    """Log-Gabor filters for an (H, W) image, built once per size (cached, read-only).

    Parameters
    ----------
    shape : (int, int)
        (H, W) of the (padded) image to filter.
    n_scales : int
        Scales (Kovesi's ``nscale``, default 4 as in [1]_ and RIFT).
    n_orient : int
        Orientations over [0, pi) (``norient``, default 6).
    min_wavelength : float
        Wavelength of the smallest scale in pixels (``minWaveLength``, 3).
    mult : float
        Ratio of successive wavelengths (``mult``, 2.1).
    sigma_onf : float
        Width of the radial Gaussian in log frequency over the centre frequency (``sigmaOnf``, 0.55).
    """
    h, w = shape
    fy = scipy.fft.fftfreq(h)[:, None]
    fx = scipy.fft.fftfreq(w)[None, :]
    radius = np.hypot(fx, fy)
    radius[0, 0] = 1.0  # log(0) guard; the DC term is zeroed below
    theta = np.arctan2(-fy, fx)  # y points down in the image, Kovesi measures angles upwards
    # Butterworth low-pass keeps the largest frequencies (the FFT's corners) out of every filter
    lowpass = 1.0 / (1.0 + (radius / 0.45) ** 30)
    log_radius = np.log(radius)
    log_sigma = 2.0 * np.log(sigma_onf) ** 2
    radial = np.empty((n_scales, h, w), np.float32)
    for s in range(n_scales):
        fo = 1.0 / (min_wavelength * mult ** s)
        radial[s] = np.exp(-(log_radius - np.log(fo)) ** 2 / log_sigma) * lowpass
    radial[:, 0, 0] = 0.0
    angles = np.arange(n_orient) * np.pi / n_orient
    out = np.empty((n_orient * n_scales, h, w), np.float32)
    for o, angle in enumerate(angles):
        # angular distance to the filter direction, wrapped to [0, pi]; raised-cosine spread of
        # half-width 2 pi / n_orient (phasecong3): zero on the opposite half plane
        dtheta = np.abs(np.remainder(theta - angle + np.pi, 2.0 * np.pi) - np.pi)
        spread = ((np.cos(np.minimum(dtheta * (n_orient / 2.0), np.pi)) + 1.0) / 2.0).astype(np.float32)
        np.multiply(radial, spread[None], out=out[o * n_scales:(o + 1) * n_scales])
    out.flags.writeable = False
    return LogGaborBank(filters=out, n_scales=n_scales, n_orient=n_orient, angles=angles)


@dataclass(frozen=True, eq=False)
class PhaseCongruency:
    """Phase congruency of an image and the log-Gabor amplitudes it was computed from.

    Attributes
    ----------
    amplitude : (n_orient, H, W) float32 ndarray
        Amplitude summed over scales per orientation (RIFT's log-Gabor layer ``A_o``).
    pc : (n_orient, H, W) float32 ndarray
        Phase congruency per orientation, in [0, 1].
    edge : (H, W) float32 ndarray
        Maximum moment of the phase congruency covariance (edges and corners), in [0, 1].
    corner : (H, W) float32 ndarray
        Minimum moment (corners only), in [0, 1].
    angles : (n_orient,) float64 ndarray
        Filter orientations (radians).
    """

    amplitude: np.ndarray
    pc: np.ndarray
    edge: np.ndarray
    corner: np.ndarray
    angles: np.ndarray


def phase_congruency(image: np.ndarray, *, n_scales: int = 4, n_orient: int = 6, min_wavelength: float = 3.0,
                     mult: float = 2.1, sigma_onf: float = 0.55, k: float = 3.0, cut_off: float = 0.5,
                     g: float = 10.0, pad: int = 16) -> PhaseCongruency:
    """Kovesi's phase congruency (``phasecong3``) of a float image in [0, 1].

    Parameters
    ----------
    image : (H, W) float ndarray
        Grey image, values in about [0, 1] (the noise threshold is absolute).
    n_scales, n_orient, min_wavelength, mult, sigma_onf
        The log-Gabor bank (:func:`log_gabor_bank`).
    k : float
        Noise threshold at the mean plus ``k`` standard deviations of the noise energy (Kovesi's
        ``k``; his default 2, here 3: the multimodal images are noisier, SAR and PET most).
    cut_off, g : float
        Frequency-spread weighting: below ``cut_off`` (0.5) of the full spread phase congruency is
        penalized by a sigmoid of gain ``g`` (10), Kovesi's defaults.
    pad : int
        Reflected border added before the FFT, pixels: keeps the periodic wrap-around of the
        FFT from making false edges at the image border.

    Returns
    -------
    PhaseCongruency
        Maps of the input's shape.
    """
    img = np.asarray(image, np.float32)
    h, w = img.shape
    off = pad if pad > 0 and min(h, w) > pad else 0  # (reflection needs more pixels than it adds)
    padded = np.pad(img, off, mode="reflect") if off else img
    ph, pw = padded.shape
    fh, fw = scipy.fft.next_fast_len(ph, real=False), scipy.fft.next_fast_len(pw, real=False)
    if (fh, fw) != (ph, pw):
        padded = np.pad(padded, ((0, fh - ph), (0, fw - pw)), mode="symmetric")
    bank = log_gabor_bank((fh, fw), n_scales=n_scales, n_orient=n_orient, min_wavelength=min_wavelength,
                          mult=mult, sigma_onf=sigma_onf)
    spectrum = scipy.fft.fft2(padded.astype(np.complex64), workers=1)
    eo = scipy.fft.ifft2(bank.filters * spectrum[None], axes=(-2, -1), workers=1, overwrite_x=True)
    eo = eo[:, off:off + h, off:off + w].reshape(n_orient, n_scales, h, w)

    amp = np.abs(eo)  # (O, S, H, W) float32
    sum_an = amp.sum(axis=1)
    max_an = amp.max(axis=1)
    total = eo.sum(axis=1)  # (O, H, W): sum of even + i odd responses over scales
    # With the unit vector of the mean phase u = conj(total) / |total|, per scale
    # E cos(mean) + O sin(mean) - |E sin(mean) - O cos(mean)| = Re(eo u) - |Im(eo u)|; the real
    # parts sum over the scales to |total|^2 / |total|, so only the imaginary parts go scale by scale.
    mag = np.abs(total)
    inv = 1.0 / (mag + np.float32(1e-6))
    u_re, u_im = total.real * inv, -total.imag * inv
    energy = mag * mag * inv
    for s in range(n_scales):
        e = eo[:, s]
        energy -= np.abs(e.real * u_im + e.imag * u_re)
    del eo

    # Noise: the smallest scale's amplitude is Rayleigh distributed where there is only noise;
    # its median gives the Rayleigh parameter (tau), summed over scales as the filters shrink.
    sub = amp[:, 0, ::2, ::2].reshape(n_orient, -1)
    tau = np.median(sub, axis=1) / np.sqrt(np.log(4.0))
    total_tau = tau * (1.0 - (1.0 / mult) ** n_scales) / (1.0 - 1.0 / mult)
    noise_mean = total_tau * np.sqrt(np.pi / 2.0)
    noise_sigma = total_tau * np.sqrt((4.0 - np.pi) / 2.0)
    threshold = (noise_mean + k * noise_sigma).astype(np.float32)
    energy = np.maximum(energy - threshold[:, None, None], 0.0)

    width = (sum_an / (max_an + _EPS) - 1.0) / max(n_scales - 1, 1)
    weight = 1.0 / (1.0 + np.exp((cut_off - width) * g))
    pc = (weight * energy / (sum_an + _EPS)).astype(np.float32)

    cos_o = np.cos(bank.angles).astype(np.float32)[:, None, None]
    sin_o = np.sin(bank.angles).astype(np.float32)[:, None, None]
    cov_x, cov_y = pc * cos_o, pc * sin_o
    # normalized by n_orient / 2 so that the moments stay in [0, 1] (Kovesi)
    a = (cov_x ** 2).sum(axis=0) / (n_orient / 2.0)
    b = 2.0 * (cov_x * cov_y).sum(axis=0) / (n_orient / 2.0)
    c = (cov_y ** 2).sum(axis=0) / (n_orient / 2.0)
    root = np.sqrt(b ** 2 + (a - c) ** 2)
    edge = 0.5 * (c + a + root)
    corner = 0.5 * (c + a - root)
    return PhaseCongruency(amplitude=sum_an.astype(np.float32), pc=pc, edge=edge.astype(np.float32),
                           corner=np.maximum(corner, 0.0).astype(np.float32), angles=bank.angles)
