"""Retroreflective licence-plate sheeting: a Mitsuba BSDF driven by an R_A table.

XML (`type="retroreflective"`), all optional except `sheeting`:

| property      | type            | unit          | default | meaning |
|---------------|-----------------|---------------|---------|---------|
| `sheeting`    | string          | -             | -       | `astm_d4956:I` / `:II` / `:III`, or `file:<csv>`; `;efficiency=F` may follow |
| `reflectance` | spectrum/texture| 1             | 0       | diffuse base (the daytime look), Lambertian |
| `retro_tint`  | spectrum/texture| 1             | 1       | spectral factor (<= 1) on R_A: coloured sheeting, transparent inks |

Spectra are bound from the scene's `[spectra]` like any reflectance, so the pre-integrated mono
render stays exact: the BSDF value is linear in each spectrum (no products of two spectra, no
clamping of spectral values), which is what `render.plan_spectra` relies on. Printed characters
are a `blendbsdf` of an ink BSDF and this one, driven by the plate bitmap (opaque ink: `diffuse`;
transparent ink: a second `retroreflective` with a `retro_tint`).

Coefficient of retroreflection (CIE 54.2-2001 "Retroreflection: definition and measurement";
ASTM E808): R_A = I / (E_perp A) in cd lx-1 m-2 (= sr-1), where I is the intensity the sample
sends toward the observer, E_perp the illuminance at the sample on a plane perpendicular to the
incident light, A the sample's area. The geometry: observation angle alpha between the
illumination and observation directions, entrance angle beta between the illumination direction
and the sheet normal.

BRDF from R_A. The observer sees the sample's intensity spread over its projected area, so the
radiance toward the observer is L = I / (A cos(theta_v)), theta_v the viewing angle from the
normal. The irradiance on the sheet is E_n = E_perp cos(beta). The BRDF is f = L / E_n, hence

    f(w_light, w_view) = R_A(alpha, beta) / (cos(beta) cos(theta_v))

(and the coefficient of retroreflected luminance R_L = L / E_perp = R_A / cos(theta_v), CIE 54.2).
Mitsuba's `eval` returns f cos(theta_o) with w_o the light direction of a camera path, i.e.
R_A / cos(theta_v).

Reciprocity. f above depends on which direction is the light through beta. A BSDF must be
symmetric (Helmholtz), so beta here is the angle between the normal and the *bisector* of the two
directions; it differs from the illumination axis's angle by at most alpha / 2 (0.25 deg at the
largest ASTM observation angle, 0.5 deg, where Type I's R_A changes by 0.6 % per 0.25 deg). In
ASTM E810's coplanar geometry the table's beta is the illumination axis's; a measurement placing
light and observer symmetrically about the tabulated beta reproduces the table exactly.

Interpolation and extrapolation of the table (documented choices, tested):
  * alpha: log R_A is linear in log alpha between nodes (a power law per segment; beaded sheeting
    divergence profiles are close to power laws, e.g. Type I: R_A ~ alpha^-0.92 from 0.2 to 0.5 deg).
    Below the first node R_A is held (a flat top: ASTM's 0.1 deg values are at most 1.2x the 0.2 deg
    ones). Beyond the last node alpha_N the last segment's power law continues, rolled off by a
    Gaussian in (alpha - alpha_N) of width sigma, and R_A = 0 beyond alpha_N + 4 sigma (where the
    roll-off is e^-8). A power law alone would hold infinite energy (R_A ~ alpha^-1 integrated over
    2 pi alpha d alpha); a hard cut would leave a camera 1-3 deg off the lamp (our car at 10-30 m)
    seeing no retroreflection at all.
  * beta (taken as |beta|: the -4 / +30 deg of ASTM are both sides of the normal): held below the
    first node, log R_A linear in beta between nodes, and beyond the last node log-linear with the
    last slope but falling at least as fast as cos(beta), so the efficiency never rises with beta
    past the table and R_A -> 0 at grazing incidence.
  * sigma bounds the energy: the retroreflected fraction of the light incident at beta,
        eta(beta) = integral f cos(theta_o) d omega_o = (1 / cos beta) * integral R_A d omega,
    (integrated over the cone around the incident direction, bisector beta included) is computed
    at construction; sigma is chosen (bisection) so that max over beta of eta equals the sheeting's
    retroreflective efficiency (3M / FHWA: beaded 7-14 %, truncated-cube prismatic ~32 %,
    full-cube ~58 %; presets use 10 %), or 5 deg if the tail never reaches it. A table whose own
    nodes already return more than the efficiency is rejected. The total albedo is eta(beta) x
    retro_tint + reflectance, and the constructor checks max(reflectance) + max eta x
    max(retro_tint) <= 1.

Sampling. With probability P_retro = eta(beta_i) t / (eta(beta_i) t + r) (t, r the channel means
of retro_tint and reflectance) the retro lobe is sampled, otherwise the cosine-weighted diffuse
base. The lobe is a cone around w_i parameterised by the chord v = |w_o - w_i| = 2 sin(alpha/2),
for which d omega = v dv d phi exactly: 512 bins uniform in v up to the lobe's end, bin probabilities
proportional to R_A x bin solid angle for the nearest of 18 rows of incident angle (0, 5, ...,
85 deg), uniform in solid angle within a bin, uniform azimuth. `pdf` evaluates the same mixture
(bin index from the chord of w_o - w_i), so `sample`, `eval` and `pdf` agree for MIS.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from poevp_optics.core.params import param
from poevp_optics.render.materials.sheeting_table import BEADED_EFFICIENCY, SheetingError, SheetingTable

#: Largest roll-off width of the tail beyond the table (used when the efficiency is never reached).
TAIL_SIGMA_MAX_DEG = 5.0
#: The lobe ends this many roll-off widths beyond the last tabulated observation angle.
TAIL_END_SIGMAS = 4.0
#: Sampling tables: chord bins per incident-angle row, and the rows' incident angles.
LOBE_BINS = 512
PROPOSAL_ROW_STEP_DEG = 5.0
PROPOSAL_ROWS = 18


_ASTM = ("ASTM D4956-01, Standard Specification for Retroreflective Sheeting for Traffic Control, "
         "Tables 2-4 (white, minimum R_A at observation / entrance angles 0.1-0.5 deg / -4, +30 deg)")

#: ASTM D4956 white sheeting minimums (cd lx-1 m-2), rows beta = 4, 30 deg.
SHEETINGS: dict[str, SheetingTable] = {
    "astm_d4956:I": SheetingTable(
        "astm_d4956:I", (0.2, 0.5), (4.0, 30.0), ((70.0, 30.0), (30.0, 15.0)), BEADED_EFFICIENCY,
        _ASTM + "; Type I (engineering grade, enclosed glass beads)"),
    "astm_d4956:II": SheetingTable(
        "astm_d4956:II", (0.2, 0.5), (4.0, 30.0), ((140.0, 50.0), (60.0, 28.0)), BEADED_EFFICIENCY,
        _ASTM + "; Type II (super engineering grade, enclosed glass beads)"),
    # 0.5 deg / +30 deg = 65 is the standard's Table 4 value; the reproduction we checked the other
    # five numbers against is cut off before it.
    "astm_d4956:III": SheetingTable(
        "astm_d4956:III", (0.1, 0.2, 0.5), (4.0, 30.0), ((300.0, 250.0, 95.0), (180.0, 150.0, 65.0)),
        BEADED_EFFICIENCY, _ASTM + "; Type III (high intensity, encapsulated glass beads)"),
}


def _read_csv_table(path: Path, efficiency: float | None) -> SheetingTable:
    """CSV rows `alpha_deg,beta_deg,ra_cd_per_lx_m2` (full grid), `#` comments; a comment line
    `# efficiency = F` gives the efficiency unless the source string sets it."""
    rows, eff = [], None
    for n, line in enumerate(path.read_text().splitlines(), 1):
        m = re.match(r"\s*#\s*efficiency\s*[=:]\s*([0-9.eE+-]+)", line)
        if m:
            eff = float(m.group(1))
        body = line.split("#", 1)[0].strip()
        if not body:
            continue
        try:
            rows.append(tuple(float(x) for x in body.split(",")))
        except ValueError:
            if rows:
                raise SheetingError(f"{path}:{n}: expected 'alpha_deg,beta_deg,ra_cd_per_lx_m2'") from None
            continue
        if len(rows[-1]) != 3:
            raise SheetingError(f"{path}:{n}: expected 3 columns")
    eff = efficiency if efficiency is not None else eff
    if eff is None:
        raise SheetingError(f"{path}: no efficiency (add '# efficiency = F' or ';efficiency=F')")
    if not rows:
        raise SheetingError(f"{path}: no data rows")
    arr = np.asarray(rows)
    alphas, betas = np.unique(arr[:, 0]), np.unique(arr[:, 1])
    grid = np.full((len(betas), len(alphas)), np.nan)
    for a, b, r in arr:
        grid[np.searchsorted(betas, b), np.searchsorted(alphas, a)] = r
    if np.any(np.isnan(grid)) or len(arr) != grid.size:
        raise SheetingError(f"{path}: rows must form a full grid of observation x entrance angles")
    return SheetingTable(f"file:{path}", tuple(alphas), tuple(betas),
                         tuple(map(tuple, grid)), float(eff), f"table file {path}")


def parse_sheeting(text: str, base_dir: Path | None = None) -> SheetingTable:
    """`astm_d4956:III`, `file:<csv>` (relative to `base_dir` or assets/), each optionally
    followed by `;efficiency=F`. Raises SheetingError naming the source."""
    if not isinstance(text, str) or not text.strip():
        raise SheetingError(f"sheeting source must be a non-empty string, got {text!r}")
    head, *opts = [p.strip() for p in text.split(";")]
    efficiency = None
    for opt in opts:
        key, _, value = opt.partition("=")
        if key.strip() != "efficiency":
            raise SheetingError(f"sheeting {text!r}: unknown option {key.strip()!r} (known: efficiency)")
        try:
            efficiency = float(value)
        except ValueError:
            raise SheetingError(f"sheeting {text!r}: efficiency must be a number") from None
    if head.startswith("file:"):
        from poevp_optics.sources.spectra import ASSETS_DIR

        p = Path(head[5:])
        cands = [p] if p.is_absolute() else [*(([base_dir / p]) if base_dir else []), ASSETS_DIR / p]
        found = next((c for c in cands if c.is_file()), None)
        if found is None:
            raise SheetingError(f"sheeting {text!r}: table file not found")
        return _read_csv_table(found.resolve(), efficiency)
    from poevp_optics.render.materials.furniture_sheeting import FURNITURE_SHEETINGS   # signs, studs

    presets = {**SHEETINGS, **FURNITURE_SHEETINGS}
    if head not in presets:
        raise SheetingError(f"sheeting {head!r}: unknown preset (known: {', '.join(presets)}, file:<csv>)")
    table = presets[head]
    if efficiency is None:
        return table
    return SheetingTable(table.name, table.alpha_deg, table.beta_deg, table.ra_cd_per_lx_m2,
                         efficiency, table.reference)


# ------------------------------------------------------------------ the R_A law (numpy or DrJit)
def _ops_numpy():
    return SimpleNamespace(minimum=np.minimum, maximum=np.maximum, log=np.log, cos=np.cos,
                           clip=np.clip, exp=np.exp)


def _ops_drjit():
    import drjit as dr

    return SimpleNamespace(minimum=dr.minimum, maximum=dr.maximum, log=dr.log, cos=dr.cos,
                           clip=dr.clip, exp=dr.exp)


def _pwl(x, xs, ys, ops, slope_right=None):
    """Piecewise-linear interpolation through (xs, ys), held constant left of xs[0] and right of
    xs[-1] unless `slope_right` continues the last segment. ys may be arrays (one per node)."""
    y = ys[0] + 0.0 * x
    for k in range(len(xs) - 1):
        t = ops.clip((x - xs[k]) / (xs[k + 1] - xs[k]), 0.0, 1.0)
        y = y + t * (ys[k + 1] - ys[k])
    if slope_right is not None:
        y = y + slope_right * ops.maximum(x - xs[-1], 0.0)
    return y


class RetroLaw:
    """R_A(alpha, beta) of a `SheetingTable` with the rules in the module docstring, the tail's
    roll-off width sigma from the efficiency bound, the lobe's end and eta(beta)."""

    def __init__(self, table: SheetingTable):
        self.table = table
        self.log_alpha = [math.log(a) for a in table.alpha_deg]
        self.beta = list(table.beta_deg)
        self.log_ra = [[math.log(r) for r in row] for row in table.ra_cd_per_lx_m2]
        self.alpha_slopes = [(row[-1] - row[-2]) / (self.log_alpha[-1] - self.log_alpha[-2])
                             for row in self.log_ra]
        self.alpha_last_deg = float(table.alpha_deg[-1])
        self.tail_sigma_deg, self.eta_rows = _kept_tail(self)
        self.alpha_end_deg = self.alpha_last_deg + TAIL_END_SIGMAS * self.tail_sigma_deg

    def log_ra_of(self, alpha_deg, beta_deg, ops):
        """ln R_A at observation angle alpha_deg and entrance angle beta_deg (>= 0), without the
        cut at alpha_end."""
        da = ops.maximum(alpha_deg - self.alpha_last_deg, 0.0)
        return self.log_ra_core(alpha_deg, beta_deg, ops) - da * da * (0.5 / self.tail_sigma_deg ** 2)

    def log_ra_core(self, alpha_deg, beta_deg, ops):
        """ln R_A without the tail's roll-off (the table's interpolation and extrapolation)."""
        la = ops.log(ops.maximum(alpha_deg, 1e-6))
        rows = [_pwl(la, self.log_alpha, r, ops, slope_right=s) for r, s in zip(self.log_ra, self.alpha_slopes)]
        val = _pwl(beta_deg, self.beta, rows, ops)
        if len(rows) > 1:
            k_beta = (rows[-1] - rows[-2]) / (self.beta[-1] - self.beta[-2])
        else:
            k_beta = 0.0 * la
        d = ops.maximum(beta_deg - self.beta[-1], 0.0)
        cos_ratio = ops.maximum(ops.cos(beta_deg * (math.pi / 180)), 1e-30) / math.cos(math.radians(self.beta[-1]))
        return val + ops.minimum(k_beta * d, ops.log(cos_ratio))

    def ra_numpy(self, alpha_deg, beta_deg) -> np.ndarray:
        """R_A (cd lx-1 m-2) including the cut at alpha_end, for numpy arrays (|beta| is used)."""
        a, b = np.asarray(alpha_deg, float), np.abs(np.asarray(beta_deg, float))
        r = np.exp(self.log_ra_of(a, b, _ops_numpy()))
        return np.where(a <= self.alpha_end_deg, r, 0.0)


def _cone_rings(law: RetroLaw, beta_i_deg: np.ndarray, alpha_deg: np.ndarray) -> np.ndarray:
    """(1 / cos beta_i) * 2 pi sin(alpha) * mean over azimuth of R_A without the tail roll-off,
    on the cone of half-angle alpha around the incident direction at beta_i, with beta the
    bisector's angle; shape (len(beta_i), len(alpha)). 32 azimuths (midpoint rule)."""
    ops = _ops_numpy()
    phi = (np.arange(32) + 0.5) * (2 * np.pi / 32)
    bi = np.radians(beta_i_deg)[:, None, None]
    a = np.radians(alpha_deg)[None, :, None]
    ph = phi[None, None, :]
    wi = np.stack(np.broadcast_arrays(np.sin(bi), 0 * bi, np.cos(bi)))
    e1 = np.stack(np.broadcast_arrays(np.cos(bi), 0 * bi, -np.sin(bi)))
    e2 = np.stack(np.broadcast_arrays(0 * bi, 1 + 0 * bi, 0 * bi))
    wo = np.cos(a) * wi + np.sin(a) * (np.cos(ph) * e1 + np.sin(ph) * e2)
    h = wi + wo
    beta_h = np.degrees(np.arctan2(np.hypot(h[0], h[1]), h[2]))
    ra = np.exp(law.log_ra_core(np.broadcast_to(np.degrees(a), beta_h.shape), beta_h, ops))
    ring = ra.mean(axis=2) * 2 * np.pi * np.sin(np.radians(alpha_deg))[None, :]
    return ring / np.cos(np.radians(beta_i_deg))[:, None]


def _eta(rings, alpha_deg, law, sigma_deg):
    """eta for each ring row with roll-off width sigma_deg, integrated up to the lobe's end."""
    da = np.maximum(alpha_deg - law.alpha_last_deg, 0.0)
    g = np.exp(-0.5 * (da / sigma_deg) ** 2) * (alpha_deg <= law.alpha_last_deg + TAIL_END_SIGMAS * sigma_deg)
    return np.trapezoid(rings * g[None, :], np.radians(alpha_deg), axis=1)


def _solve_tail(law: RetroLaw) -> tuple[float, np.ndarray]:
    """Tail roll-off width sigma (deg) at which max over beta of eta equals the efficiency (by
    bisection; TAIL_SIGMA_MAX_DEG if never reached), and eta at the proposal rows."""
    t = law.table
    alpha_max = law.alpha_last_deg + TAIL_END_SIGMAS * TAIL_SIGMA_MAX_DEG
    alpha = np.unique(np.concatenate([np.linspace(0.0, t.alpha_deg[0], 40),
                                      np.geomspace(t.alpha_deg[0], alpha_max, 1200),
                                      np.asarray(t.alpha_deg)]))
    rings = _cone_rings(law, np.arange(0.0, 89.5, 1.0), alpha)
    core = np.trapezoid(rings * (alpha <= law.alpha_last_deg)[None, :], np.radians(alpha), axis=1).max()
    if core > t.efficiency:
        raise SheetingError(f"sheeting {t.name!r}: its table alone returns {core:.3f} of the light "
                            f"(within {law.alpha_last_deg} deg), above its efficiency {t.efficiency}")
    lo, hi = 1e-3, TAIL_SIGMA_MAX_DEG
    if _eta(rings, alpha, law, hi).max() <= t.efficiency:
        sigma = hi
    else:
        for _ in range(60):
            mid = math.sqrt(lo * hi)
            lo, hi = (mid, hi) if _eta(rings, alpha, law, mid).max() < t.efficiency else (lo, mid)
        sigma = lo
    rows = np.arange(PROPOSAL_ROWS) * PROPOSAL_ROW_STEP_DEG
    return sigma, _eta(_cone_rings(law, rows, alpha), alpha, law, sigma)


#: Bump when `_solve_tail`'s answer for a table changes: the kept answers are then solved again.
TAIL_CACHE_VERSION = 1


def _kept_tail(law: RetroLaw) -> tuple[float, np.ndarray]:
    """`_solve_tail(law)`, solved once per table and kept on disk (cache folder `retro/`;
    core/cache.py: checksummed, rebuilt when damaged), keyed on the table's numbers and the
    constants its answer depends on. The quadrature takes 1-1.5 s a table on the 2-core machine,
    paid by every process that loads a scene with the sheeting (the night road's markings and
    signs: 2.5 s of its 5.5 s load) and now by the first one only."""
    from poevp_optics.core.cache import cache_file, cached, json_digest, save_npz

    t = law.table
    key = json_digest([t.alpha_deg, t.beta_deg, t.ra_cd_per_lx_m2, t.efficiency, TAIL_SIGMA_MAX_DEG, TAIL_END_SIGMAS,
                       PROPOSAL_ROWS, PROPOSAL_ROW_STEP_DEG, TAIL_CACHE_VERSION], algo="sha256", length=32)

    def load(path):
        with np.load(path) as z:
            return float(z["sigma_deg"]), np.array(z["eta_rows"])

    def problem(v):
        sigma, eta = v
        if not (math.isfinite(sigma) and 0 < sigma <= TAIL_SIGMA_MAX_DEG):
            return f"sigma {sigma} deg outside (0, {TAIL_SIGMA_MAX_DEG}]"
        if eta.shape != (PROPOSAL_ROWS,) or not np.all(np.isfinite(eta)) or np.any(eta < 0):
            return f"eta rows {eta.shape}: not {PROPOSAL_ROWS} finite values >= 0"
        return None

    def save(tmp, v):
        save_npz(tmp, {"sigma_deg": np.float64(v[0]), "eta_rows": np.asarray(v[1], np.float64)})

    return cached(cache_file("retro", f"tail-{key}.npz"), lambda: _solve_tail(law), load=load, save=save,
                  check=problem)


@functools.lru_cache(maxsize=32)
def retro_law(table: SheetingTable) -> RetroLaw:
    """Cached `RetroLaw` (its tail's quadrature is kept on disk too: `_kept_tail`)."""
    return RetroLaw(table)


def lobe_proposal(law: RetroLaw) -> tuple[np.ndarray, np.ndarray, float]:
    """Sampling tables: (pmf[rows, bins], exclusive cdf[rows, bins], chord bin width)."""
    v_end = 2 * math.sin(math.radians(law.alpha_end_deg) / 2)
    edges = np.linspace(0.0, v_end, LOBE_BINS + 1)
    mid_alpha_deg = np.degrees(2 * np.arcsin(0.25 * (edges[1:] + edges[:-1])))
    area = np.pi * (edges[1:] ** 2 - edges[:-1] ** 2)
    rows = np.arange(PROPOSAL_ROWS) * PROPOSAL_ROW_STEP_DEG
    w = law.ra_numpy(mid_alpha_deg[None, :], rows[:, None]) * area[None, :]
    pmf = w / w.sum(axis=1, keepdims=True)
    cdf = np.concatenate([np.zeros((PROPOSAL_ROWS, 1)), np.cumsum(pmf, axis=1)[:, :-1]], axis=1)
    return pmf, cdf, v_end / LOBE_BINS


# ------------------------------------------------------------------ the Mitsuba plugin
def _spectrum_mean(s):
    """Channel mean of a Mitsuba spectrum (mono: the value; spectral: over its wavelengths)."""
    import drjit as dr

    return dr.sum(s, axis=0) / len(s) if len(s) > 1 else s[0]


#: Mitsuba and DrJit, bound by `_make_bsdf_class` (a plugin class needs a variant to exist).
mi = dr = None


class _RetroreflectiveBSDFMethods:
    """Mitsuba BSDF `retroreflective` (see the module docstring)."""

    def __init__(self, props):
        mi.BSDF.__init__(self, props)
        if "sheeting" not in props.keys():
            raise SheetingError("retroreflective BSDF: the 'sheeting' property is required")
        self._init_law(parse_sheeting(str(props["sheeting"])), props)

    def _init_law(self, table, props):
        """Set up the lobe of `table` with the `reflectance` and `retro_tint` of `props` (also
        used by materials/road_marking.py, whose tables come from EN 1436 classes)."""
        self.table = table
        self.law = retro_law(self.table)
        self.reflectance = props.get_texture("reflectance", 0.0)
        self.retro_tint = props.get_texture("retro_tint", 1.0)
        top = float(self.reflectance.max()) + float(self.law.eta_rows.max()) * float(self.retro_tint.max())
        if top > 1 + 1e-6:
            raise SheetingError(f"retroreflective BSDF ({self.table.name}): reflectance max "
                                f"{float(self.reflectance.max()):.3f} + efficiency "
                                f"{float(self.law.eta_rows.max()):.3f} x retro_tint max exceeds 1: "
                                "energy would not be conserved")
        pmf, cdf, dv = lobe_proposal(self.law)
        self._pmf = mi.Float(pmf.ravel().astype(np.float32))
        self._cdf = mi.Float(cdf.ravel().astype(np.float32))
        self._eta_rows = mi.Float(self.law.eta_rows.astype(np.float32))
        self._dv = float(dv)
        self._ops = _ops_drjit()
        glossy = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
        diffuse = mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
        self.m_components = [glossy, diffuse]
        self.m_flags = glossy | diffuse

    # -------------------------------------------------------------- pieces
    def _row(self, cos_theta_i):
        beta_deg = dr.acos(dr.clip(cos_theta_i, -1.0, 1.0)) * (180 / math.pi)
        return dr.minimum(mi.UInt32(dr.round(beta_deg / PROPOSAL_ROW_STEP_DEG)), PROPOSAL_ROWS - 1)

    def _retro_prob(self, ctx, si, active):
        has_retro = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0)
        has_diffuse = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 1)
        if not has_diffuse:
            return mi.Float(1.0)
        if not has_retro:
            return mi.Float(0.0)
        eta = dr.gather(mi.Float, self._eta_rows, self._row(mi.Frame3f.cos_theta(si.wi)), active)
        w_r = eta * _spectrum_mean(self.retro_tint.eval(si, active))
        w_d = _spectrum_mean(self.reflectance.eval(si, active))
        return dr.select(w_r + w_d > 0, w_r / dr.maximum(w_r + w_d, 1e-30), 0.5)

    def _lobe_pdf(self, wi, wo, active):
        v = dr.norm(wo - wi)
        k = mi.UInt32(dr.floor(v / self._dv))
        inside = active & (v < self._dv * LOBE_BINS)
        idx = self._row(mi.Frame3f.cos_theta(wi)) * LOBE_BINS + dr.minimum(k, LOBE_BINS - 1)
        pmf = dr.gather(mi.Float, self._pmf, idx, inside)
        v0 = mi.Float(k) * self._dv
        area = math.pi * (dr.square(v0 + self._dv) - dr.square(v0))
        return dr.select(inside, pmf / area, 0.0)

    def _retro_f_cos(self, si, wo, active):
        """f cos(theta_o) of the retro lobe: R_A(alpha, beta_h) t / cos(theta_i)."""
        wi = si.wi
        v = dr.norm(wo - wi)
        alpha_deg = 2 * dr.asin(dr.minimum(0.5 * v, 1.0)) * (180 / math.pi)
        h = wi + wo
        beta_deg = dr.atan2(dr.sqrt(dr.square(h.x) + dr.square(h.y)), h.z) * (180 / math.pi)
        ra = dr.exp(self.law.log_ra_of(alpha_deg, beta_deg, self._ops))
        ra = dr.select(alpha_deg <= self.law.alpha_end_deg, ra, 0.0)
        cos_i = mi.Frame3f.cos_theta(wi)
        return self.retro_tint.eval(si, active) * (ra / dr.maximum(cos_i, 1e-12))

    def _eval_pdf(self, ctx, si, wo, active):
        cos_i, cos_o = mi.Frame3f.cos_theta(si.wi), mi.Frame3f.cos_theta(wo)
        active = active & (cos_i > 0) & (cos_o > 0)
        has_retro = ctx.is_enabled(mi.BSDFFlags.GlossyReflection, 0)
        has_diffuse = ctx.is_enabled(mi.BSDFFlags.DiffuseReflection, 1)
        value = mi.Spectrum(0.0)
        if has_retro:
            value += self._retro_f_cos(si, wo, active)
        if has_diffuse:
            value += self.reflectance.eval(si, active) * (cos_o / math.pi)
        p_retro = self._retro_prob(ctx, si, active)
        pdf = p_retro * self._lobe_pdf(si.wi, wo, active) + (1 - p_retro) * (cos_o / math.pi)
        return (dr.select(active, value, 0.0), dr.select(active, pdf, 0.0))

    # -------------------------------------------------------------- BSDF interface
    def eval(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)[0]

    def pdf(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)[1]

    def eval_pdf(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)

    def sample(self, ctx, si, sample1, sample2, active=True):
        wi = si.wi
        active = active & (mi.Frame3f.cos_theta(wi) > 0)
        p_retro = self._retro_prob(ctx, si, active)
        pick_retro = sample1 < p_retro
        # retro lobe: bin by binary search on the row's exclusive CDF, v^2 uniform in the bin
        base = self._row(mi.Frame3f.cos_theta(wi)) * LOBE_BINS
        u = sample2.x
        k = mi.UInt32(0)
        step = LOBE_BINS // 2
        while step >= 1:
            cand = k + step
            k = dr.select(dr.gather(mi.Float, self._cdf, base + cand, active) <= u, cand, k)
            step //= 2
        c0 = dr.gather(mi.Float, self._cdf, base + k, active)
        pk = dr.gather(mi.Float, self._pmf, base + k, active)
        xi = dr.clip((u - c0) / dr.maximum(pk, 1e-30), 0.0, 1.0)
        v0 = mi.Float(k) * self._dv
        v = dr.sqrt(dr.square(v0) + xi * (dr.square(v0 + self._dv) - dr.square(v0)))
        cos_a = 1 - 0.5 * dr.square(v)
        sin_a = v * dr.sqrt(dr.maximum(1 - 0.25 * dr.square(v), 0.0))
        s_phi, c_phi = dr.sincos(2 * math.pi * sample2.y)
        wo_retro = mi.Frame3f(wi).to_world(mi.Vector3f(sin_a * c_phi, sin_a * s_phi, cos_a))
        wo_diff = mi.warp.square_to_cosine_hemisphere(sample2)
        wo = dr.select(pick_retro, wo_retro, wo_diff)

        value, pdf = self._eval_pdf(ctx, si, wo, active)
        bs = dr.zeros(mi.BSDFSample3f)
        bs.wo = wo
        bs.pdf = pdf
        bs.eta = 1.0
        bs.sampled_component = dr.select(pick_retro, mi.UInt32(0), mi.UInt32(1))
        bs.sampled_type = dr.select(pick_retro, mi.UInt32(+mi.BSDFFlags.GlossyReflection),
                                    mi.UInt32(+mi.BSDFFlags.DiffuseReflection))
        ok = active & (pdf > 0)
        weight = dr.select(ok, value / dr.maximum(pdf, 1e-30), 0.0)
        return bs, weight

    def eval_diffuse_reflectance(self, si, active=True):
        return self.reflectance.eval(si, active)

    def traverse(self, callback):
        callback.put("reflectance", self.reflectance, mi.ParamFlags.Differentiable)
        callback.put("retro_tint", self.retro_tint, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys):
        pass

    def to_string(self):
        return (f"RetroreflectiveBSDF[sheeting={self.table.name!r}, efficiency={self.table.efficiency}, "
                f"tail_sigma_deg={self.law.tail_sigma_deg:.3f}]")


def _make_bsdf_class():
    """The `RetroreflectiveBSDF` plugin class of the current Mitsuba variant."""
    global mi, dr
    import drjit
    import mitsuba

    mi, dr = mitsuba, drjit
    methods = {k: v for k, v in vars(_RetroreflectiveBSDFMethods).items() if k not in ("__dict__", "__weakref__", "__module__")}
    return type("RetroreflectiveBSDF", (mi.BSDF,), methods)   # nanobind classes take one base: the methods are copied in

def register() -> None:
    """Register `retroreflective` with the active Mitsuba variant (materials.register_plugins)."""
    import mitsuba as mi

    cls = _make_bsdf_class()
    mi.register_bsdf("retroreflective", lambda props: cls(props))


@dataclass(frozen=True)
class SheetingSpec:
    """[sheeting.<param>]: retroreflective sheeting bound to `$<param>` of a `retroreflective` BSDF:
    an R_A table (`source`) and its efficiency bound (NaN: the preset's)."""

    source: str = param()
    efficiency: float = param(math.nan, gt=0, lt=1)


def sheeting_string(sh: SheetingSpec, base_dir: Path) -> str:
    """The `sheeting` property string a [sheeting.<param>] entry binds (file paths made absolute)."""
    source = sh.source
    if source.startswith("file:") and not Path(source[5:]).is_absolute() and (base_dir / source[5:]).is_file():
        source = f"file:{(base_dir / source[5:]).resolve()}"
    return source if math.isnan(sh.efficiency) else f"{source};efficiency={sh.efficiency:.9g}"
