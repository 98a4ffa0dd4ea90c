"""Point lamps shaped by a photometric file: a Mitsuba emitter `photometric`, registered from Python.

XML:

| property       | type     | unit       | meaning |
|----------------|----------|------------|---------|
| `intensity`    | spectrum | W sr-1 nm-1| the lamp's *peak* spectral intensity (its `[spectra]` entry: `intensity_cd` is the peak) |
| `distribution` | string   | -          | path of an IES LM-63 (`.ies`) or EULUMDAT (`.ldt`) file, bound as `$<param>_distribution` |
| `to_world`     | transform| m          | pose: local +z is the lamp's reference axis, +y up (a `lookat` works as for `spot`) |

Intensity toward a direction d: I(lambda, d) = intensity(lambda) x C(d) / C_max, with C the file's
candela table interpolated bilinearly in the file's own angles (the rule of photompy's
`Photometry.get_intensity`); directions outside the table's angular range get 0. So the scene's
`intensity_cd` is the peak of the beam and the file gives its shape; `file_peak_cd` reports the
file's own peak (write it as `intensity_cd` to use the file's absolute candela).

Coordinates (ANSI/IESNA LM-63-2002 section 3, "Key definitions"; emitter-local x = left of the
beam, as Mitsuba's look_at builds it):
  * Type A (IES photometric type 3, the automotive convention): photometric planes are vertical
    and share the vertical axis; H (horizontal angle, clockwise seen from above: + = right) and
    V (vertical angle, + = up, 0 = horizontal): d = (-sin H cos V, sin V, cos H cos V).
  * Type C (IES type 1, and every EULUMDAT file): polar axis vertical, gamma from the nadir
    (gamma = 0 down), C planes counter-clockwise seen from above with C = 0 along the lamp's +z:
    d = (sin gamma sin C, -cos gamma, sin gamma cos C). A headlamp's beam is near gamma = 90, C = 0.
  * Type B is not supported (its plane/angle convention is not settled among readers); convert it.

Why a Python emitter rather than `spot`/`projector` with a baked texture: a spot's texture is
sampled on the gnomonic plane tan(theta) < tan(cutoff) (< 90 deg) and interpolated there, so the
file's nodes and a low beam's 0.1-deg cut-off are reproduced only approximately, and the
`projector` plugin carries a factor pi (FACTS.md). Here the file's own grid is interpolated
exactly; the DrJit code is traced once per kernel, so it costs what a C++ emitter costs per lane.
Light tracing (`sample_ray`) importance-samples the table's cells (uniform in solid angle within a
cell, cell probability ~ max corner x cell solid angle), so weights stay bounded.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np


class LampFileError(ValueError):
    """A photometric file that cannot be used (message names the file)."""


@dataclass(frozen=True)
class LampDistribution:
    """A candela table on its file's angular grid (full range, symmetry expanded).

    system: "A" (h = H, v = V, degrees) or "C" (h = C, v = gamma, degrees);
    candela[i_h, i_v]: absolute luminous intensity from the file (cd).
    """

    path: str
    system: str
    h_deg: np.ndarray
    v_deg: np.ndarray
    candela: np.ndarray

    @property
    def peak_cd(self) -> float:
        return float(self.candela.max())

    def relative(self, h_deg, v_deg) -> np.ndarray:
        """C / C_max at file angles (numpy; bilinear, 0 outside the table)."""
        return _bilinear_np(self, np.asarray(h_deg, float), np.asarray(v_deg, float)) / self.peak_cd

    def angles_of(self, d_local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """File angles (deg) of emitter-local unit directions d_local[..., 3]."""
        x, y, z = d_local[..., 0], d_local[..., 1], d_local[..., 2]
        if self.system == "A":
            return np.degrees(np.arctan2(-x, z)), np.degrees(np.arcsin(np.clip(y, -1, 1)))
        c = np.degrees(np.arctan2(x, z)) % 360.0
        return c, np.degrees(np.arccos(np.clip(-y, -1, 1)))


def _bilinear_np(dist: LampDistribution, h, v):
    hs, vs, val = dist.h_deg, dist.v_deg, dist.candela
    inside = (h >= hs[0]) & (h <= hs[-1]) & (v >= vs[0]) & (v <= vs[-1])
    i = np.clip(np.searchsorted(hs, h, side="right") - 1, 0, len(hs) - 2)
    j = np.clip(np.searchsorted(vs, v, side="right") - 1, 0, len(vs) - 2)
    th = np.clip((h - hs[i]) / (hs[i + 1] - hs[i]), 0, 1)
    tv = np.clip((v - vs[j]) / (vs[j + 1] - vs[j]), 0, 1)
    out = ((1 - th) * (1 - tv) * val[i, j] + th * (1 - tv) * val[i + 1, j]
           + (1 - th) * tv * val[i, j + 1] + th * tv * val[i + 1, j + 1])
    return np.where(inside, out, 0.0)


def _check(path, h, v, cd, system):
    if len(h) < 2 or len(v) < 2 or np.any(np.diff(h) <= 0) or np.any(np.diff(v) <= 0):
        raise LampFileError(f"{path}: angles must increase strictly, with >= 2 of each")
    if cd.shape != (len(h), len(v)) or not np.all(np.isfinite(cd)) or np.any(cd < 0) or cd.max() <= 0:
        raise LampFileError(f"{path}: candela values must be finite, >= 0, and not all 0")
    return LampDistribution(str(path), system, h.astype(float), v.astype(float), cd.astype(float))


def _read_ies(path: Path) -> LampDistribution:
    import warnings

    from photompy import IESFile, PhotometricType

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ies = IESFile.read(path, strict=False)
            phot = ies.photometry
            kind = phot.photometric_type
            if kind == PhotometricType.B:
                raise LampFileError(f"{path}: IES photometric type B is not supported (use type A or C)")
            exp = phot.expanded()
    except LampFileError:
        raise
    except Exception as e:  # noqa: BLE001 - photompy raises many types on malformed files
        raise LampFileError(f"{path}: cannot read IES file: {e}") from None
    # photompy: values[i_phi, i_theta]; phi = horizontal angle, theta = vertical angle
    h, v, cd = np.asarray(exp.phis, float), np.asarray(exp.thetas, float), np.asarray(exp.values, float)
    if kind == PhotometricType.C:
        h, cd = _close_c_planes(h, cd)
        return _check(path, h, v, cd, "C")
    return _check(path, h, v, cd, "A")


def _close_c_planes(c, cd):
    """Append the C = 360 plane (a copy of C = 0) so interpolation wraps around."""
    if c[0] == 0 and c[-1] < 360:
        c = np.append(c, 360.0)
        cd = np.concatenate([cd, cd[:1]], axis=0)
    return c, cd


def _read_ldt(path: Path) -> LampDistribution:
    from pyldt import LdtReader

    try:
        ldt = LdtReader.read(str(path))
    except Exception as e:  # noqa: BLE001
        raise LampFileError(f"{path}: cannot read EULUMDAT file: {e}") from None
    hd = ldt.header
    c = np.asarray(hd.c_angles, float)
    g = np.asarray(hd.g_angles, float)
    rel = np.asarray(ldt.intensities, float)                 # cd per 1000 lm, [C, gamma]
    flux_lm = float(sum(n * f for n, f in zip(hd.num_lamps, hd.lamp_flux)))
    if flux_lm <= 0:
        raise LampFileError(f"{path}: lamp flux must be > 0 to give absolute candela")
    cd = rel * flux_lm / 1000.0 * (hd.conv_factor or 1.0)
    c, cd = _close_c_planes(c, cd)
    return _check(path, c, g, cd, "C")


@functools.lru_cache(maxsize=16)
def load_distribution(path: str) -> LampDistribution:
    """Read an `.ies` (photompy) or `.ldt` (eulumdat-py) file into a `LampDistribution`."""
    p = Path(path)
    if not p.is_file():
        raise LampFileError(f"{p}: photometric file not found")
    suffix = p.suffix.lower()
    if suffix == ".ies":
        return _read_ies(p)
    if suffix == ".ldt":
        return _read_ldt(p)
    raise LampFileError(f"{p}: unknown photometric file type (want .ies or .ldt)")


def resolve_distribution(source: str, base_dir: Path | None = None) -> Path:
    """`file:<path>` (relative to `base_dir`, then assets/) -> an existing absolute path."""
    from poevp_optics.sources.spectra import ASSETS_DIR

    if not isinstance(source, str) or not source.startswith("file:"):
        raise LampFileError(f"distribution must look like 'file:lamps/high_beam.ies', got {source!r}")
    p = Path(source[5:])
    cands = [p] if p.is_absolute() else [*([base_dir / p] if base_dir else []), ASSETS_DIR / p]
    for c in cands:
        if c.is_file():
            load_distribution(str(c.resolve()))      # validate now: errors name the file
            return c.resolve()
    raise LampFileError(f"{source}: photometric file not found (looked in {', '.join(map(str, cands))})")


# ------------------------------------------------------------------ the Mitsuba plugin
class _AxisLookup:
    """Cell index of an angle on a non-uniform axis in two gathers: a uniform bucket table (bucket
    width at most half the smallest node spacing, so a bucket holds at most one node) gives the
    cell at the bucket's start, and one comparison moves past a node inside the bucket."""

    MAX_BUCKETS = 1 << 20

    def __init__(self, mi, nodes: np.ndarray):
        spacing = float(np.min(np.diff(nodes)))
        self.x0 = float(nodes[0])
        n_buckets = int(min(self.MAX_BUCKETS, math.ceil((nodes[-1] - nodes[0]) / (0.5 * spacing)) + 1))
        self.inv_width = (n_buckets - 1) / float(nodes[-1] - nodes[0])
        starts = self.x0 + np.arange(n_buckets) / self.inv_width
        cells = np.clip(np.searchsorted(nodes, starts, side="right") - 1, 0, len(nodes) - 2)
        if n_buckets == self.MAX_BUCKETS and np.any(np.diff(cells) > 1):
            raise LampFileError("photometric table too fine for the bucket lookup")
        self.n_buckets = n_buckets
        self.cells = mi.UInt32(cells.astype(np.uint32))
        self.nodes = mi.Float(nodes.astype(np.float32))
        self.n = len(nodes)

    def __call__(self, mi, dr, x, active):
        b = mi.UInt32(dr.clip((x - self.x0) * self.inv_width, 0, self.n_buckets - 1))
        i = dr.gather(mi.UInt32, self.cells, b, active)
        nxt = dr.gather(mi.Float, self.nodes, dr.minimum(i + 1, self.n - 1), active)
        return dr.select((x >= nxt) & (i + 1 < self.n - 1), i + 1, i)


#: Mitsuba and DrJit, bound by `_make_emitter_class` (a plugin class needs a variant to exist).
mi = dr = None


class _PhotometricEmitterMethods:
    """Mitsuba emitter `photometric` (see the module docstring)."""

    def __init__(self, props):
        mi.Emitter.__init__(self, props)
        if "distribution" not in props.keys():
            raise LampFileError("photometric emitter: the 'distribution' property (file path) is required")
        self.dist = load_distribution(str(Path(str(props["distribution"])).resolve()))
        if "intensity" not in props.keys():
            raise LampFileError("photometric emitter: the 'intensity' spectrum (the beam's peak) is required")
        self.intensity = props.get_emissive_texture("intensity")
        m = np.array(props["to_world"].matrix if "to_world" in props.keys() else np.eye(4), dtype=np.float32)
        self.to_world = mi.Transform4f(m)
        self._to_local = self.to_world.inverse()
        dr.make_opaque(self._to_local)
        d = self.dist
        self._h = mi.Float(d.h_deg.astype(np.float32))
        self._v = mi.Float(d.v_deg.astype(np.float32))
        self._rel = mi.Float((d.candela / d.peak_cd).astype(np.float32).ravel())
        self._nv = len(d.v_deg)
        self._h_lookup, self._v_lookup = _AxisLookup(mi, d.h_deg), _AxisLookup(mi, d.v_deg)
        self._build_sampler()
        self.m_flags = mi.EmitterFlags.DeltaPosition

    # ------------------------------------------------------------ distribution
    def _angles(self, dl):
        deg = 180 / math.pi
        if self.dist.system == "A":
            return dr.atan2(-dl.x, dl.z) * deg, dr.asin(dr.clip(dl.y, -1, 1)) * deg
        c = dr.atan2(dl.x, dl.z) * deg
        return dr.select(c < 0, c + 360, c), dr.acos(dr.clip(-dl.y, -1, 1)) * deg

    def relative(self, d_local, active=True):
        """C(d) / C_max for emitter-local unit directions (bilinear in file angles, 0 outside)."""
        h, v = self._angles(d_local)
        d = self.dist
        inside = active & (h >= d.h_deg[0]) & (h <= d.h_deg[-1]) & (v >= d.v_deg[0]) & (v <= d.v_deg[-1])
        i = self._h_lookup(mi, dr, h, inside)
        j = self._v_lookup(mi, dr, v, inside)
        h0, h1 = dr.gather(mi.Float, self._h, i, inside), dr.gather(mi.Float, self._h, i + 1, inside)
        v0, v1 = dr.gather(mi.Float, self._v, j, inside), dr.gather(mi.Float, self._v, j + 1, inside)
        th = dr.clip((h - h0) / (h1 - h0), 0, 1)
        tv = dr.clip((v - v0) / (v1 - v0), 0, 1)
        k = i * self._nv + j
        c00 = dr.gather(mi.Float, self._rel, k, inside)
        c01 = dr.gather(mi.Float, self._rel, k + 1, inside)
        c10 = dr.gather(mi.Float, self._rel, k + self._nv, inside)
        c11 = dr.gather(mi.Float, self._rel, k + self._nv + 1, inside)
        val = (1 - th) * ((1 - tv) * c00 + tv * c01) + th * ((1 - tv) * c10 + tv * c11)
        return dr.select(inside, val, 0.0)

    def _build_sampler(self):
        """Cell distribution for sample_ray: weight = max corner x cell solid angle."""
        d = self.dist
        c = d.candela / d.peak_cd
        cmax = np.maximum.reduce([c[:-1, :-1], c[1:, :-1], c[:-1, 1:], c[1:, 1:]])
        hr, vr = np.radians(d.h_deg), np.radians(d.v_deg)
        if d.system == "A":      # d omega = cos V dV dH
            solid = np.diff(hr)[:, None] * np.diff(np.sin(vr))[None, :]
        else:                    # d omega = sin gamma d gamma dC
            solid = np.diff(hr)[:, None] * -np.diff(np.cos(vr))[None, :]
        w = (cmax * solid).ravel()
        self._cell_solid = mi.Float(solid.ravel().astype(np.float32))
        self._cells = mi.DiscreteDistribution(w.astype(np.float32))
        self._ncell_v = len(d.v_deg) - 1

    def _sample_local_direction(self, u):
        idx, u2 = self._cells.sample_reuse(u.x)
        i, j = idx // self._ncell_v, idx % self._ncell_v
        h0, h1 = dr.gather(mi.Float, self._h, i), dr.gather(mi.Float, self._h, i + 1)
        v0, v1 = dr.gather(mi.Float, self._v, j), dr.gather(mi.Float, self._v, j + 1)
        rad = math.pi / 180
        h = (h0 + u2 * (h1 - h0)) * rad
        if self.dist.system == "A":
            sv = dr.lerp(dr.sin(v0 * rad), dr.sin(v1 * rad), u.y)
            cv = dr.safe_sqrt(1 - sv * sv)
            dl = mi.Vector3f(-dr.sin(h) * cv, sv, dr.cos(h) * cv)
        else:
            cg = dr.lerp(dr.cos(v0 * rad), dr.cos(v1 * rad), u.y)
            sg = dr.safe_sqrt(1 - cg * cg)
            dl = mi.Vector3f(sg * dr.sin(h), -cg, sg * dr.cos(h))
        pdf = self._cells.eval_pmf_normalized(idx) / dr.gather(mi.Float, self._cell_solid, idx)
        return dl, pdf

    # ------------------------------------------------------------ Emitter interface
    def _position(self):
        return self.to_world @ mi.Point3f(0.0, 0.0, 0.0)

    def _spectral(self, it_or_si, active):
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wavelengths = it_or_si.wavelengths
        return self.intensity.eval(si, active)

    def sample_direction(self, it, sample, active=True):
        p = self._position()
        ds = dr.zeros(mi.DirectionSample3f)
        ds.p = p
        ds.time = it.time
        ds.pdf = 1.0
        ds.delta = True
        ds.emitter = mi.EmitterPtr(self)
        d = p - it.p
        dist = dr.norm(d)
        ds.d = d / dist
        ds.dist = dist
        local = self._to_local @ (-ds.d)
        value = self._spectral(it, active) * (self.relative(dr.normalize(local), active) / dr.square(dist))
        return ds, dr.select(active, value, 0.0)

    def eval_direction(self, it, ds, active=True):
        local = self._to_local @ (-ds.d)
        value = self._spectral(it, active) * (self.relative(dr.normalize(local), active) / dr.square(ds.dist))
        return dr.select(active, value, 0.0)

    def pdf_direction(self, it, ds, active=True):
        return mi.Float(0.0)

    def sample_ray(self, time, wavelength_sample, spatial_sample, direction_sample, active=True):
        si = dr.zeros(mi.SurfaceInteraction3f)
        wavelengths, spec_weight = self.intensity.sample_spectrum(
            si, mi.math.sample_shifted(wavelength_sample), active)
        dl, pdf = self._sample_local_direction(direction_sample)
        weight = spec_weight * (self.relative(dl, active) / dr.maximum(pdf, 1e-30))
        ray = mi.Ray3f(self._position(), dr.normalize(self.to_world @ dl), time, wavelengths)
        return ray, dr.select(active & (pdf > 0), weight, 0.0)

    def sample_wavelengths(self, si, sample, active=True):
        return self.intensity.sample_spectrum(si, mi.math.sample_shifted(sample), active)

    def sample_position(self, time, sample, active=True):
        ps = dr.zeros(mi.PositionSample3f)
        ps.p = self._position()
        ps.time = time
        ps.pdf = 1.0
        ps.delta = True
        return ps, mi.Float(1.0)

    def pdf_position(self, ps, active=True):
        return mi.Float(0.0)

    def eval(self, si, active=True):
        return mi.Spectrum(0.0)

    def bbox(self):
        p = np.array(self._position(), dtype=float).ravel()
        return mi.ScalarBoundingBox3f(mi.ScalarPoint3f(*map(float, p[:3])))

    def traverse(self, callback):
        mi.Emitter.traverse(self, callback)      # `sampling_weight` (light selection: render/lights.py)
        callback.put("to_world", self.to_world, mi.ParamFlags.NonDifferentiable)
        callback.put("intensity", self.intensity, mi.ParamFlags.Differentiable)

    def parameters_changed(self, keys):
        mi.Emitter.parameters_changed(self, keys)
        self._to_local = self.to_world.inverse()
        dr.make_opaque(self._to_local)

    def to_string(self):
        return f"PhotometricEmitter[distribution={self.dist.path!r}, system={self.dist.system}]"


def _make_emitter_class():
    """The `PhotometricEmitter` plugin class of the current Mitsuba variant."""
    global mi, dr
    import drjit
    import mitsuba

    mi, dr = mitsuba, drjit
    methods = {k: v for k, v in vars(_PhotometricEmitterMethods).items() if k not in ("__dict__", "__weakref__", "__module__")}
    return type("PhotometricEmitter", (mi.Emitter,), methods)   # nanobind classes take one base: the methods are copied in

def register() -> None:
    """Register `photometric` with the active Mitsuba variant (materials.register_plugins)."""
    import mitsuba as mi

    cls = _make_emitter_class()
    mi.register_emitter("photometric", lambda props: cls(props))
