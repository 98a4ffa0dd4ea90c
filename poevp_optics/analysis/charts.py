"""Dynamic range from a test chart: patch statistics, DR in dB by named method, what binds it.

All DR figures are 20 log10 of a luminance ratio (dB; one density unit = 20 dB).

| method     | definition | source |
|------------|------------|--------|
| `iso15739` | L_max / L_min, L_min the lowest luminance whose incremental signal-to-temporal-noise ratio SNR_inc = L dS/dL / sigma_t is >= 1 | ISO 15739:2017 (via CIE e-ILV 17-612; Imatest "DR at SNR 1") |
| `snr10`    | the same at SNR_inc >= 10 ("good" quality) | Imatest dynamic-range documentation |
| `emva`     | per pixel, sensor alone: mu_e,sat / mu_e,min, mu_e,min the signal with SNR = 1 over read, dark-shot and quantisation noise | EMVA 1288 Release 4.0 (linear), Sec. 4.4 |

Chart measurements: S is the linear radiance estimate of each capture (DN minus offset, divided
by gain and by the pixel's known effective exposure: the reconstruction, but not clamped at 0,
so the noise near black is not rectified); per patch, the mean over its inner pixels and the N
captures, and sigma_t the RMS over pixels of the per-pixel standard deviation across captures
(fixed-pattern noise excluded, as ISO 15739 asks). L dS/dL = dS/d ln L is a finite difference
over the patch sequence (a constant flare pedestal drops out of it, its shot noise does not).
The optics' flare pedestal on each patch (light spread from its neighbours) is subtracted
from S before the difference, as a flare measurement on a black surround would allow. L_min is interpolated in log-log between the patches around the threshold. L_max: the standard
takes the brightest unclipped patch; since the response is linear we refine it within one patch
step to that patch's saturation luminance, L x (clip level / S) (reported with the
patch-quantised value). A patch is clipped when more than 0.1 % of its samples sit at the top
code (EMVA 1288 R4's saturation criterion).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from poevp_optics.core.params import param
from poevp_optics.core.registry import Registry

CLIPPED_SAMPLE_FRACTION = 1e-3

#: DR methods by name (module table): the chart ones carry their incremental-SNR threshold.
DR_METHODS = Registry("dynamic-range method")
DR_METHODS.register("iso15739", 1.0, source="ISO 15739:2017 (via CIE e-ILV 17-612; Imatest DR at SNR 1)")
DR_METHODS.register("snr10", 10.0, source="Imatest dynamic-range documentation: SNR_inc >= 10")
DR_METHODS.register("emva", None, source="EMVA 1288 Release 4.0 (linear), Sec. 4.4: per pixel, sensor alone")


def chart_methods() -> dict[str, float]:
    """The DR methods measured on the chart's patches: name -> SNR_inc threshold."""
    return {n: DR_METHODS[n] for n in DR_METHODS if DR_METHODS[n] is not None}


@dataclass(frozen=True)
class ChartSpec:
    """[chart]: back-lit transmissive dynamic-range chart; absent (patches = 0): not a chart.

    Patch i has density D_i (equal steps from d_min to d_max, or the explicit `densities`) and
    is bound to the XML parameter `$<param_prefix>NN`: its radiance is the light box's
    (`source`, `luminance_cd_per_m2`) times 10^-D_i (a neutral film over a Lambertian box).
    """

    patches: int = param(0, min=0, max=1000)
    d_min: float = param(0.0, min=0, max=20)
    d_max: float = param(8.0, min=0, max=20)
    densities: tuple[float, ...] = param((), min=0, max=20)
    source: str = param("cie:LED-B5")
    luminance_cd_per_m2: float = param(1.0e5, gt=0)
    param_prefix: str = param("patch_")
    repeats: int = param(16, min=2, max=4096)            # captures for the temporal noise
    roi_inset_px: int = param(4, min=1, max=1000)        # patch border left out (edges, PSF)
    mask_source: str = param("loop", choices=("loop", "oracle"))
    max_iterations: int = param(12, min=1, max=1000)     # loop frames allowed to settle the mask
    reference_camera: str = param("")                    # scene whose camera sections are also run

    def density_list(self) -> tuple[float, ...]:
        if self.densities:
            return self.densities
        return tuple(float(d) for d in np.linspace(self.d_min, self.d_max, self.patches))

    def param(self, i: int) -> str:
        return f"{self.param_prefix}{i:02d}"


@dataclass
class PatchTable:
    """Per-patch statistics of one camera configuration, sorted by ascending luminance."""

    index: np.ndarray          # patch number in the chart
    density: np.ndarray
    luminance_cd_m2: np.ndarray
    true_signal: np.ndarray    # ground-truth photon radiance, e- s-1 m-2 sr-1
    mean_signal: np.ndarray    # mean linear estimate, same unit
    temporal_noise: np.ndarray
    clip_signal: np.ndarray    # estimate at which the patch's pixels clip
    clipped: np.ndarray        # bool
    snr: np.ndarray            # incremental SNR (NaN where clipped)
    mean_electrons: np.ndarray # mean signal electrons (flare included)
    flare_electrons: np.ndarray  # noise-free electrons spread in by the optics (objective, relay), mean
    pixels: np.ndarray
    pedestal: np.ndarray       # relay flare pedestal, in the patch's estimate unit

    def rows(self) -> list[dict]:
        keys = ["index", "density", "luminance_cd_m2", "true_signal", "mean_signal",
                "pedestal", "temporal_noise", "snr", "clipped", "mean_electrons", "flare_electrons", "pixels"]
        out = []
        for j in range(len(self.index)):
            row = {}
            for k in keys:
                v = getattr(self, k)[j]
                row[k] = bool(v) if k == "clipped" else (int(v) if k in ("index", "pixels") else
                                                         (None if not np.isfinite(v) else float(v)))
            out.append(row)
        return out


def patch_regions(truth: np.ndarray, expected: np.ndarray, inset_px: int,
                  stderr: np.ndarray | None = None) -> list[np.ndarray]:
    """Boolean image per patch: pixels whose rendered radiance equals the patch's closed-form
    value (relative 1e-3 plus 4 MC standard errors; partial edge pixels fail), eroded by
    `inset_px` (PSF core, registration)."""
    import cv2

    k = np.ones((2 * inset_px + 1, 2 * inset_px + 1), np.uint8)
    t = truth.astype(np.float64)
    tol = 0.0 if stderr is None else 4.0 * stderr.astype(np.float64)
    out = []
    for v in expected:
        sel = (np.abs(t - v) <= 1e-3 * v + tol).astype(np.uint8)
        out.append(cv2.erode(sel, k, borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool))
    return out


def patch_table(regions, densities, luminance, true_signal, estimates, saturated,
                clip_signal, electrons, scale, flare_e) -> PatchTable:
    """Statistics per patch from N captures.

    estimates: (N, H, W) linear radiance estimates; saturated: (N, H, W) bool; clip_signal:
    (H, W) estimate of a clipped pixel; electrons: (N, H, W) signal electrons from DN; scale:
    (H, W) electrons per unit estimate; flare_e: (H, W) noise-free electrons minus those of the
    patch's own radiance (the relay PSF's pedestal, known exactly here: what a flawless
    black-surround flare measurement, ISO 18844, would give), converted by the patch's scale.
    """
    n = len(regions)
    mean = np.empty(n)
    noise = np.empty(n)
    clipped = np.zeros(n, bool)
    clip = np.empty(n)
    mean_e = np.empty(n)
    flare = np.empty(n)
    ped = np.zeros(n)
    pixels = np.empty(n, int)
    for i, reg in enumerate(regions):
        v = estimates[:, reg]                              # (N, P)
        pixels[i] = v.shape[1]
        mean[i] = float(v.mean())
        noise[i] = float(np.sqrt(np.mean(v.var(axis=0, ddof=1))))
        clipped[i] = float(saturated[:, reg].mean()) > CLIPPED_SAMPLE_FRACTION
        clip[i] = float(clip_signal[reg].mean())
        mean_e[i] = float(electrons[:, reg].mean())
        flare[i] = float(flare_e[reg].mean())
        ped[i] = flare[i] / float(scale[reg].mean())
    order = np.argsort(luminance)
    lum = np.asarray(luminance, float)[order]
    table = PatchTable(np.arange(n)[order], np.asarray(densities, float)[order], lum,
                       np.asarray(true_signal, float)[order], mean[order], noise[order],
                       clip[order], clipped[order], np.full(n, np.nan), mean_e[order],
                       flare[order], pixels[order], ped[order])
    table.snr = incremental_snr(table)
    return table


def incremental_snr(t: PatchTable) -> np.ndarray:
    """SNR_inc = (dS / d ln L) / sigma_t on the unclipped patches (NaN on clipped ones), S less
    the relay's flare pedestal (a pedestal that varies from patch to patch would otherwise
    pass for signal in the finite difference; its shot noise stays in sigma_t)."""
    snr = np.full(len(t.index), np.nan)
    ok = ~t.clipped
    if ok.sum() < 2:
        return snr
    ln_l = np.log(t.luminance_cd_m2[ok])
    slope = np.gradient(t.mean_signal[ok] - t.pedestal[ok], ln_l)
    sig = t.temporal_noise[ok]
    with np.errstate(divide="ignore", invalid="ignore"):
        # no temporal noise at all: the quantiser swallowed the signal (codes never change)
        s = np.where(sig > 0, slope / sig, 0.0)
    snr[ok] = s
    return snr


def dynamic_range(t: PatchTable, threshold: float) -> dict:
    """L_max / L_min at an incremental-SNR threshold; which end the chart itself limits."""
    ok = np.flatnonzero(~t.clipped)
    if len(ok) < 2:
        return {"db": None, "why": "fewer than two unclipped patches"}
    lum = t.luminance_cd_m2
    top = ok[-1]                                         # brightest unclipped patch
    headroom = t.clip_signal[top] / t.mean_signal[top] if t.mean_signal[top] > 0 else 1.0
    chart_top = top == len(lum) - 1                      # nothing clipped: the chart ran out
    if chart_top:
        l_max = lum[top]
    else:
        l_max = lum[top] * min(max(headroom, 1.0), lum[top + 1] / lum[top])
    # walk down from the brightest unclipped patch to the first one under the threshold
    snr = t.snr
    l_min, chart_bottom = None, False
    j = top
    while j > 0 and j - 1 in set(ok) and snr[j - 1] >= threshold:
        j -= 1
    if snr[j] < threshold:
        return {"db": 0.0, "why": f"no unclipped patch reaches SNR {threshold:g}",
                "l_max_cd_m2": float(l_max), "l_min_cd_m2": None}
    if j == 0 or (j - 1) not in set(ok):
        l_min, chart_bottom = lum[j], True
    else:
        a, b = j - 1, j                                  # snr[a] < thr <= snr[b]
        la, lb = math.log(lum[a]), math.log(lum[b])
        sa, sb = snr[a], snr[b]
        if sa > 0 and np.isfinite(sb):
            x = (math.log(threshold) - math.log(sa)) / (math.log(sb) - math.log(sa))
        else:
            x = (threshold - sa) / (sb - sa) if np.isfinite(sb) else 1.0
        l_min = math.exp(la + min(max(x, 0.0), 1.0) * (lb - la))
    return {"db": float(20 * math.log10(l_max / l_min)),
            "patch_quantised_db": float(20 * math.log10(lum[top] / lum[j])),
            "l_max_cd_m2": float(l_max), "l_min_cd_m2": float(l_min),
            "limited_by_chart": {"top": bool(chart_top), "bottom": bool(chart_bottom)}}


def sensor_noise_floor_e(p, exposure_s: float) -> float:
    """Temporal dark noise in electrons: read, dark-current shot, ADC quantisation (EMVA 1288)."""
    return math.sqrt(p.read_noise_e ** 2 + p.dark_current_e_per_s * exposure_s
                     + (1.0 / p.gain_dn_per_e) ** 2 / 12.0)


def emva_dr(p, exposure_s: float) -> dict:
    """EMVA 1288 R4.0 per-pixel DR: SNR(mu) = mu / sqrt(sigma_d^2 + mu) = 1 at
    mu_min = (1 + sqrt(1 + 4 sigma_d^2)) / 2; mu_sat = the saturation capacity."""
    sd = sensor_noise_floor_e(p, exposure_s)
    mu_min = 0.5 * (1 + math.sqrt(1 + 4 * sd * sd))
    mu_sat = p.saturation_capacity_e
    return {"db": float(20 * math.log10(mu_sat / mu_min)), "mu_sat_e": float(mu_sat),
            "mu_min_e": float(mu_min), "sigma_d_e": float(sd)}


LIMIT_WORDS = {"white_fill": "the DMD's white fill outside its display window",
               "dmd_contrast": "the DMD contrast ratio (off-state leakage)",
               "mask_bit_depth": "the mask bit depth (smallest PWM step)",
               "chart": "the chart itself (its densest or clearest patch)",
               "sensor_noise": "sensor temporal noise (read, dark, quantisation)",
               "relay_flare": "relay flare (light spread from brighter patches by the relay's PSF and glare)",
               "objective_flare": "objective flare (light spread from brighter patches by the objective's "
                                  "PSF and veiling glare, before the DMD)",
               "optics_flare": "flare of the objective and the relay (light spread from brighter patches)"}


def attribute(ldr: dict, enc: dict, parts: dict, table_enc: PatchTable, noise_floor_e: float,
              flare: tuple[str, str] = ("relay_flare", "")) -> dict:
    """Which limit binds each end of the encoded DR, with the numbers behind it. `flare`: the
    LIMIT_WORDS key of the optics that spread the light (apps/run/chart.py flare_source) and the
    words naming them ("" : LIMIT_WORDS')."""
    upper = parts["binding"]
    if enc.get("limited_by_chart", {}).get("top"):
        upper = "chart"
    lower = "sensor_noise"
    if enc.get("limited_by_chart", {}).get("bottom"):
        lower = "chart"
    elif enc.get("l_min_cd_m2"):
        j = int(np.argmin(np.abs(np.log(table_enc.luminance_cd_m2 / enc["l_min_cd_m2"]))))
        spread_e = max(table_enc.flare_electrons[j], 0.0)
        if spread_e > noise_floor_e ** 2:                   # flare shot noise above the dark noise
            lower = flare[0]
    gain = None
    if ldr.get("l_max_cd_m2") and enc.get("l_max_cd_m2"):
        gain = float(20 * math.log10(enc["l_max_cd_m2"] / ldr["l_max_cd_m2"]))
    return {"upper_end": upper, "lower_end": lower, "measured_gain_db": gain,
            "available_gain_db": parts["gain_db"], "transmission_floor": parts["floor"],
            "floor_parts": parts["parts"],
            "explanation": (f"upper end set by {LIMIT_WORDS[upper]}; lower end by "
                            f"{flare[1] if lower == flare[0] and flare[1] else LIMIT_WORDS[lower]}. "
                            f"The darkest usable mask level passes {parts['floor']:.3g} of white "
                            f"({parts['gain_db']:.1f} dB of headroom above the LDR saturation)")}
