"""A differentiable camera for one frame: the gradient of a smooth objective (the plate's white
against the band) with respect to the paper's Eq. 2 mask-law coefficients (Vs, a, b), through
the law, the DMD's bit-plane PWM exposure, the mirror-to-sensor registration, the relay PSF and
the sensor's transfer, by DrJit's automatic differentiation (reverse mode, `drjit.llvm.ad`,
float64). It lives in control/ because it runs a mask law (masks.py) through the camera.

Which parts of the camera run in AD-capable DrJit: none as they are. The DMD gather, the
registration taps and the sensor run in DrJit on `drjit.auto.Float` (no AD graph), the mask
law, the relay PSF (OpenCV / FFT convolution) and the objective's blur in NumPy. This module
rebuilds the chain after the objective on `drjit.llvm.ad.Float64` from the camera's own tables
and kernels (camera.py `capture` is the reference; the test checks the electrons equal its
`signal`), with these relaxations, each a smooth stand-in for a step the exact camera takes:

| stage | exact camera | here (for the gradient) |
|---|---|---|
| law's threshold at Vs | M = 255 below Vs | weight sigmoid((x - Vs) / step_dn) between 255 and the attenuated branch (exactly 1 at a clipped prediction, x >= 254.5, which is above every Vs < 255) |
| law at x -> 255 | limit a^inf = 0 | 255 - x floored at `edge_dn` (0.5: a^((255 - b Vs) / 0.5), effectively 0) |
| mask levels | rounded to integers | continuous; the per-level PWM table (dmd.py `transmission_table`, exact) interpolated by a C1 cubic (Catmull-Rom) between levels |
| sensor | full-well and ADC clip, rounding, noise | mean response, no rounding; clips replaced by soft minima of width `clip_width` (DN) |

The objective is J = (w - t)^2 with w the mean of DN / max DN over the plate's box on the
sensor grid (computed from the mirrors the box reads alone: the registration, the relay PSF and
the crop composed into one sparse matrix; `objective_full` runs the whole frame, the same J) (a smooth stand-in for the report's 90th percentile) and t the middle of the band
[band_low, band_high]. The radiance (the objective's image on the mirrors, `Camera.dmd_image`)
and the predicted frame (its smooth envelope, masks.py) do not depend on (Vs, a, b): they enter
as constants.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poevp_optics.camera.dmd import transmission_table

#: Parameter names, in the order of `value_and_grad`'s vector.
COEFFICIENTS = ("vs", "a", "b")
#: 8-bit value from which a prediction is clipped (control/loop_step.py CLIP_MARKER).
CLIP_MARKER = 254.5


@dataclass(frozen=True)
class Relaxation:
    """Widths of the smooth stand-ins (module docstring): step_dn for the law's threshold (8-bit
    DN), edge_dn the floor of 255 - x, clip_width the soft clips' width (DN)."""

    step_dn: float = 2.0
    edge_dn: float = 0.5
    clip_width: float = 2.0


def _soft_min(x, c: float, width: float):
    """min(x, c) smoothed over `width`: x - width softplus((x - c) / width) (exact far from c)."""
    import drjit as dr

    z = (x - c) / width
    softplus = dr.select(z > 30.0, z, dr.log(1.0 + dr.exp(dr.minimum(z, 30.0))))
    return x - width * softplus


class FrameModel:
    """One frame of `camera` as a function of (Vs, a, b): build once (the constants), then
    `value_and_grad(theta)` or `value(theta)`.

    subframes: the frame's K radiance samples (render grid, as RenderedExposure.subframes);
    times_s: their times (None: K uniform nodes); pred_8bit: the predicted frame on the mirror
    grid (8-bit scale) the law reads; box: the plate's box on the sensor grid (y0, x0, y1, x1);
    band: (low, high) fractions of full scale; smooth_px: the law's own key; mirror_box: the
    plate's box on the mirror grid (the frame's roi), which names a clipped prediction as the
    reason of a flat start."""

    def __init__(self, camera, subframes, frame_index: int, pred_8bit, box, band=(0.4, 0.9), *,
                 times_s=None, smooth_px: float = 4.0, relax: Relaxation = Relaxation(), mirror_box=None):
        from drjit.llvm.ad import Float64

        from poevp_optics.control.masks import smooth_envelope

        self.camera, self.relax, self.box = camera, relax, tuple(int(v) for v in box)
        self.mirror_box = tuple(int(v) for v in mirror_box) if mirror_box is not None else None
        self.target = 0.5 * (band[0] + band[1])
        k = len(subframes)
        self.nodes = [Float64(np.asarray(camera.dmd_image(s), np.float64).ravel()) for s in subframes]
        env = smooth_envelope(np.clip(np.asarray(pred_8bit, np.float64), 0.0, 255.0), smooth_px)
        self.env_np = np.asarray(env, np.float64)
        self.env = Float64(self.env_np.ravel())
        rel = camera.nodes_rel(frame_index, k, times_s)
        self.table = transmission_table(np.arange(camera.top_level + 1), camera.dmd_spec,
                                        camera.schedule(frame_index), rel)          # (levels + 1, K), s
        self.smooth_px = smooth_px
        self._arrays: dict = {}

    def _const(self, name: str, make):
        """A constant DrJit array built once (`make()`), then the same buffer on every call: an
        array made afresh from NumPy may differ in alignment, which changes the compiled kernel
        and costs a new LLVM compilation per evaluation."""
        if name not in self._arrays:
            self._arrays[name] = make()
        return self._arrays[name]

    # ------------------------------------------------------------------ stages
    def levels(self, vs, a, b, exact: bool = False, env=None):
        """Mirror levels from the law (continuous, or the camera's rounded ones with exact), on
        every mirror or on the predicted values `env` of some of them."""
        import drjit as dr

        r, x, top = self.relax, self.env if env is None else env, self.camera.top_level
        expo = (x - b * vs) / dr.maximum(255.0 - x, r.edge_dn)
        att = dr.exp(expo * dr.log(a))
        att = dr.minimum(att, 1.0)
        if exact:
            from poevp_optics.control.masks import threshold_exp

            m255 = threshold_exp(self.env_np, float(vs[0]), float(a[0]), float(b[0]))
            return np.clip(np.rint(m255 * top / 255.0), 0, top)
        # a clipped prediction (>= CLIP_MARKER) is above every Vs < 255: the law attenuates it
        # exactly (no smooth threshold there, whose tail would leak light the camera never passes)
        step = dr.select(x >= CLIP_MARKER, 1.0, 1.0 / (1.0 + dr.exp(-(x - vs) / r.step_dn)))
        m255 = 255.0 * ((1.0 - step) + step * att)
        return m255 * (top / 255.0)

    def weights(self, v):
        """Each node's exposure (s) per mirror at continuous levels v: Catmull-Rom in the level."""
        import drjit as dr
        from drjit.llvm.ad import Float64, UInt32

        top = self.camera.top_level
        v = dr.clip(v, 0.0, float(top))
        l0 = dr.clip(dr.floor(dr.detach(v)), 0.0, float(top - 1))
        f = v - l0
        li = UInt32(l0)
        idx = [dr.select(li > 0, li - 1, li), li, li + 1, dr.minimum(li + 2, UInt32(top))]
        f2, f3 = f * f, f * f * f
        h00, h10, h01, h11 = 2 * f3 - 3 * f2 + 1, f3 - 2 * f2 + f, -2 * f3 + 3 * f2, f3 - f2
        out = []
        for j in range(self.table.shape[1]):
            col = self._const(f"table{j}", lambda j=j: Float64(self.table[:, j]))
            pm, p0, p1, p2 = (dr.gather(Float64, col, i) for i in idx)
            m0 = dr.select(li > 0, 0.5 * (p1 - pm), p1 - p0)
            m1 = dr.select(li + 2 <= top, 0.5 * (p2 - p0), p1 - p0)
            out.append(h00 * p0 + h10 * m0 + h01 * p1 + h11 * m1)
        return out

    def electrons(self, v):
        """Signal electrons on the sensor grid (flattened) for levels v (AD Float64 or NumPy)."""
        import drjit as dr
        from drjit.llvm.ad import Float64, UInt32

        cam = self.camera
        if isinstance(v, np.ndarray):              # exact integer levels: the table's own rows
            w = [Float64(self.table[np.asarray(v, np.int64).ravel(), j]) for j in range(self.table.shape[1])]
        else:
            w = self.weights(v)
        plane = w[0] * self.nodes[0]
        for j in range(1, len(w)):
            plane = dr.fma(w[j], self.nodes[j], plane)
        if cam.taps is not None:
            idx, tw = cam.taps
            acc = None
            for j in range(idx.shape[1]):
                ij = self._const(f"tap_idx{j}", lambda j=j: UInt32(idx[:, j].astype(np.uint32)))
                wj = self._const(f"tap_w{j}", lambda j=j: Float64(tw[:, j]))
                g = dr.gather(Float64, plane, ij) * wj
                acc = g if acc is None else acc + g
            plane = acc
        if cam.psf is not None:
            plane = self._convolve(plane, cam.psf.kernel)
        plane = self._crop(plane)
        return plane * float(cam.electrons_per_radiance())

    def _convolve(self, plane, kernel: np.ndarray):
        """Same-size convolution, the image continued by reflection (OpenCV BORDER_REFLECT, as
        camera/convolution.py convolve_reflect), as gathers: linear in `plane`."""
        import drjit as dr
        from drjit.llvm.ad import Float64, UInt32

        h, w = self.camera.extended_shape
        c = kernel.shape[0] // 2
        ys, xs = np.divmod(np.arange(h * w), w)

        def reflect(i, n):
            i = np.where(i < 0, -i - 1, i)
            return np.where(i >= n, 2 * n - i - 1, i)

        out = None
        for dy in range(kernel.shape[0]):
            for dx in range(kernel.shape[1]):
                kv = float(kernel[dy, dx])
                if kv == 0.0:
                    continue
                src = self._const(f"psf{dy},{dx}", lambda dy=dy, dx=dx: UInt32(
                    (reflect(ys - (dy - c), h) * w + reflect(xs - (dx - c), w)).astype(np.uint32)))
                g = dr.gather(Float64, plane, src) * kv
                out = g if out is None else out + g
        return dr.maximum(out, 0.0)

    def _crop(self, plane):
        import drjit as dr
        from drjit.llvm.ad import Float64, UInt32

        g, (h, w) = self.camera.sensor_guard_px, self.camera.shape
        eh, ew = self.camera.extended_shape
        if g == 0 and (eh, ew) == (h, w):
            return plane
        ys, xs = np.divmod(np.arange(h * w), w)
        idx = self._const("crop", lambda: UInt32(((ys + g) * ew + xs + g).astype(np.uint32)))
        return dr.gather(Float64, plane, idx)

    def dn(self, e):
        """Mean DN with soft clips (full well, ADC top) for the gradient."""
        p, r = self.camera.params, self.relax
        dark = (p.dark_current_e_per_s * self.camera.timing.exposure_s
                if self.camera.sensor.switches.dark_current else 0.0)
        e = _soft_min(e + dark, float(p.full_well_e), r.clip_width / p.gain_dn_per_e)
        return _soft_min(p.offset_dn + p.gain_dn_per_e * e, float(p.max_dn), r.clip_width)

    def objective(self, dn):
        """(w - t)^2, w = the box's mean DN / max DN (module docstring)."""
        import drjit as dr
        from drjit.llvm.ad import Float64, UInt32

        h, w = self.camera.shape
        y0, x0, y1, x1 = self.box
        yy, xx = np.mgrid[y0:y1, x0:x1]
        idx = self._const("box", lambda: UInt32((yy * w + xx).ravel().astype(np.uint32)))
        inside = dr.gather(Float64, dn, idx)
        white = dr.sum(inside) / float(inside.shape[0] * self.camera.params.max_dn)
        return (white - self.target) ** 2

    # ------------------------------------------------------------------ the plate's box only
    def _box_operator(self):
        """The chain mirror plane -> sensor electrons (registration taps, relay PSF with
        reflected borders, crop) restricted to the plate's box, as one sparse matrix: (rows: box
        pixel, cols: index into `support`, vals) and `support`, the mirrors it reads. Linear
        before the PSF's clamp at 0, which acts per box pixel (`_objective_box`)."""
        if "box_op" in self._arrays:
            return self._arrays["box_op"]
        import scipy.sparse as sp

        cam = self.camera
        g, (h, w) = cam.sensor_guard_px, cam.shape
        eh, ew = cam.extended_shape
        y0, x0, y1, x1 = self.box
        yy, xx = np.mgrid[y0:y1, x0:x1]
        rows_ext = ((yy + g) * ew + xx + g).ravel()
        n = rows_ext.size
        if cam.psf is not None:                    # box pixel <- extended pixels (convolve_reflect)
            k = cam.psf.kernel
            c = k.shape[0] // 2
            ys, xs = np.divmod(rows_ext, ew)

            def reflect(i, m):
                i = np.where(i < 0, -i - 1, i)
                return np.where(i >= m, 2 * m - i - 1, i)

            r, cidx, v = [], [], []
            for dy in range(k.shape[0]):
                for dx in range(k.shape[1]):
                    if k[dy, dx] != 0.0:
                        r.append(np.arange(n))
                        cidx.append(reflect(ys - (dy - c), eh) * ew + reflect(xs - (dx - c), ew))
                        v.append(np.full(n, float(k[dy, dx])))
            psf = sp.csr_matrix((np.concatenate(v), (np.concatenate(r), np.concatenate(cidx))), shape=(n, eh * ew))
        else:
            psf = sp.csr_matrix((np.ones(n), (np.arange(n), rows_ext)), shape=(n, eh * ew))
        mirrors = cam.mirror_shape[0] * cam.mirror_shape[1]
        if cam.taps is not None:                   # extended pixel <- mirrors (area average)
            idx, tw = cam.taps
            reg = sp.csr_matrix((tw.ravel(), (np.repeat(np.arange(idx.shape[0]), idx.shape[1]), idx.ravel())),
                                shape=(eh * ew, mirrors))
        else:
            reg = sp.identity(mirrors, format="csr")
        m = (psf @ reg).tocoo()
        keep = m.data != 0.0
        support, cols = np.unique(m.col[keep], return_inverse=True)
        self._arrays["box_op"] = (m.row[keep], cols, m.data[keep], support)
        return self._arrays["box_op"]

    def _objective_box(self, vs, a, b):
        """J from the plate's box alone: the law, the exposure and the chain only on the mirrors
        the box reads (`_box_operator`); the same J as the whole frame's (`objective_full`)."""
        import drjit as dr
        from drjit.llvm.ad import Float64, UInt32

        rows, cols, vals, support = self._box_operator()
        cam = self.camera
        sub = self._const("box_env", lambda: Float64(self.env_np.ravel()[support]))
        nodes = [self._const(f"box_node{j}", lambda j=j: Float64(np.asarray(self.nodes[j].numpy())[support]))
                 for j in range(len(self.nodes))]
        w = self.weights(self.levels(vs, a, b, env=sub))
        plane = w[0] * nodes[0]
        for j in range(1, len(w)):
            plane = dr.fma(w[j], nodes[j], plane)
        g = dr.gather(Float64, plane, self._const("box_cols", lambda: UInt32(cols.astype(np.uint32))))
        g = g * self._const("box_vals", lambda: Float64(vals))
        n = (self.box[2] - self.box[0]) * (self.box[3] - self.box[1])
        e = dr.zeros(Float64, n)
        dr.scatter_reduce(dr.ReduceOp.Add, e, g, self._const("box_rows", lambda: UInt32(rows.astype(np.uint32))))
        if cam.psf is not None:
            e = dr.maximum(e, 0.0)
        dn = self.dn(e * float(cam.electrons_per_radiance()))
        white = dr.sum(dn) / float(n * cam.params.max_dn)
        return (white - self.target) ** 2

    # ------------------------------------------------------------------ value and gradient
    def value_and_grad(self, theta) -> tuple[float, np.ndarray]:
        """J and dJ/d(Vs, a, b) at theta = (Vs, a, b) (reverse-mode AD, over the plate's box)."""
        import drjit as dr
        from drjit.llvm.ad import Float64

        vs, a, b = (Float64(float(t)) for t in theta)
        dr.make_opaque(vs, a, b)        # evaluated, not literals: one compiled kernel for every theta
        for t in (vs, a, b):
            dr.enable_grad(t)
        j = self._objective_box(vs, a, b)
        dr.backward(j)
        return float(j[0]), np.array([float(dr.grad(t)[0]) for t in (vs, a, b)])

    def value(self, theta) -> float:
        """J at theta without the AD graph (over the plate's box)."""
        import drjit as dr
        from drjit.llvm.ad import Float64

        vs, a, b = (Float64(float(t)) for t in theta)
        dr.make_opaque(vs, a, b)
        return float(self._objective_box(vs, a, b)[0])

    def objective_full(self, theta) -> float:
        """J at theta through the whole frame's chain (electrons on every sensor pixel)."""
        import drjit as dr
        from drjit.llvm.ad import Float64

        vs, a, b = (Float64(float(t)) for t in theta)
        dr.make_opaque(vs, a, b)
        return float(self.objective(self.dn(self.electrons(self.levels(vs, a, b))))[0])

    def exact_electrons(self, theta) -> np.ndarray:
        """Signal electrons (sensor grid) at the camera's own rounded levels: the reference the
        test compares with `Camera.capture`'s."""
        from drjit.llvm.ad import Float64

        vs, a, b = (Float64(float(t)) for t in theta)
        v = self.levels(vs, a, b, exact=True)
        return np.array(self.electrons(v)).reshape(self.camera.shape)


# ---------------------------------------------------------------------------- gradient refinement
@dataclass(frozen=True)
class Refinement:
    """What `refine` did: the start and end coefficients and objective, the start's gradient
    (per unit of each bound's width), the optimiser's iterations, and `note`: why it could not
    move when the objective is flat there ("" when it moved)."""

    theta0: tuple[float, float, float]
    theta: tuple[float, float, float]
    value0: float
    value: float
    grad0: tuple[float, float, float]
    iterations: int
    note: str = ""


def refine(model, theta0, bounds, *, max_iter: int = 50, flat_rel: float = 1e-9) -> Refinement:
    """Minimise the model's smooth objective from `theta0` within `bounds` ((low, high) per
    coefficient, COEFFICIENTS order; low == high holds that coefficient fixed) by L-BFGS-B
    (SciPy) on its reverse-mode gradient, the free coefficients scaled to [0, 1] by their
    bounds. `model`: a FrameModel or a FrameMean (several frames, several scenes). A start whose
    scaled gradient is below `flat_rel` x the objective in every free coefficient is flat: the
    result says why (no plate pixel above Vs, or the plate clipped) instead of moving."""
    from scipy.optimize import minimize

    lo = np.array([b[0] for b in bounds], np.float64)
    span = np.array([b[1] - b[0] for b in bounds], np.float64)
    if np.any(span < 0):
        raise ValueError(f"refine: bounds {bounds} have a low above its high")
    free = span > 0
    theta0 = np.clip(np.asarray(theta0, np.float64), lo, lo + span)
    value0, g0 = model.value_and_grad(theta0)
    g0s = np.where(free, g0 * span, 0.0)
    if not free.any():
        return Refinement(tuple(theta0), tuple(theta0), value0, value0, tuple(g0s), 0,
                          "no coefficient is free to move (every bound is a single value)")
    if np.all(np.abs(g0s[free]) <= flat_rel * max(abs(value0), 1e-300)):
        return Refinement(tuple(theta0), tuple(theta0), value0, value0, tuple(g0s), 0, flat_reason(model, theta0))

    def full(u):
        theta = theta0.copy()
        theta[free] = lo[free] + u * span[free]
        return theta

    def fun(u):
        v, g = model.value_and_grad(full(u))
        return v, (g * span)[free]

    res = minimize(fun, (theta0[free] - lo[free]) / span[free], jac=True, method="L-BFGS-B",
                   bounds=[(0.0, 1.0)] * int(free.sum()), options={"maxiter": max_iter})
    theta = full(np.clip(res.x, 0.0, 1.0))
    value = model.value(theta)
    if value > value0:                        # never worse than the start
        theta, value = theta0, value0
    return Refinement(tuple(theta0), tuple(theta), value0, value, tuple(g0s), int(res.nit))


class FrameMean:
    """The mean of several FrameModels' objectives (the frames of a run after its white
    initialisation, over one or more scenes): what `refine` minimises for a search."""

    def __init__(self, models: list[FrameModel]):
        if not models:
            raise ValueError("FrameMean: no frame to average")
        self.models = list(models)

    def value_and_grad(self, theta) -> tuple[float, np.ndarray]:
        vg = [m.value_and_grad(theta) for m in self.models]
        return (float(np.mean([v for v, _ in vg])), np.mean([g for _, g in vg], axis=0))

    def value(self, theta) -> float:
        return float(np.mean([m.value(theta) for m in self.models]))


def flat_reason(model, theta) -> str:
    """Why the objective does not move at `theta` (a FrameModel or a FrameMean): the plate's
    predicted values against Vs in every frame, or its capture at the top of the sensor's range
    in every frame."""
    frames = model.models if isinstance(model, FrameMean) else [model]
    reasons = {_flat_reason(m, theta) for m in frames}
    return reasons.pop() if len(reasons) == 1 else "flat: the capture does not depend on the coefficients here"


def _flat_reason(model: FrameModel, theta) -> str:
    """Why the objective does not move at `theta`: the plate's predicted values against Vs, or
    its capture at the top of the sensor's range."""
    from drjit.llvm.ad import Float64

    cam = model.camera
    y0, x0, y1, x1 = model.box
    dn = np.array(model.dn(model.electrons(model.levels(*(Float64(float(t)) for t in theta))))).reshape(cam.shape)
    if np.mean(dn[y0:y1, x0:x1] >= cam.params.max_dn - model.relax.clip_width) > 0.99:
        return "flat: the plate is clipped at the top of the sensor's range for every nearby setting"
    reach = float(theta[0]) - 6 * model.relax.step_dn        # the smooth threshold's reach below Vs
    if not np.any(model.env_np >= reach):
        return (f"flat: no predicted value reaches Vs = {float(theta[0]):.4g} (the law leaves every mirror "
                "white), so no coefficient changes the capture")
    if model.mirror_box is not None:
        my0, mx0, my1, mx1 = model.mirror_box
        x = model.env_np[my0:my1, mx0:mx1].astype(np.float64)
        x = x[x >= reach]
        vs, a, b = (float(t) for t in theta)
        with np.errstate(over="ignore", under="ignore"):
            att = a ** ((x - b * vs) / np.maximum(255.0 - x, model.relax.edge_dn))
        if x.size and np.all(att < 1e-6) and np.min(x) >= 250.0:
            return (f"flat: the plate's prediction is clipped ({np.min(x):.1f}-{np.max(x):.1f} of 255) wherever it "
                    f"reaches Vs: the paper's law 255 a^((x - b Vs) / (255 - x)) passes less than 1e-6 of its "
                    "light there, at these coefficients and all nearby")
    return "flat: the capture does not depend on the coefficients here"
