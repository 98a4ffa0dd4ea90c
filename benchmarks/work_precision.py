"""Work-precision of the camera's accuracy settings: error against wall time, log-log.

* PSF support: an Airy PSF (f/8, IMX253 band) truncated at 90 % ... 99.999 % encircled energy,
  applied to a 368x640 scene with a 1e6:1 highlight (the automatic support is capped at 257 px);
  error = relative L1 difference from a 513 px kernel
  (time = the convolution).
* float32 vs float64: the DrJit float32 noise-free chain (K = 8 sub-frames, random mask) against
  a float64 NumPy evaluation of the same sum; and the float64 NumPy chain's own time.
* Poisson sampler: our exact DrJit sampler (Knuth below 10, PTRS above) against the Gaussian
  approximation N(lambda, lambda) rounded and NumPy's generator, at lambda = 0.5, 3, 30, 3e4:
  error = Kolmogorov distance of 1e6 draws to the exact Poisson CDF, time per 1e6 draws.

    .venv/bin/python -m benchmarks.work_precision [--results]
"""

from __future__ import annotations

import argparse

import numpy as np

from benchmarks.common import (add_results_flag, machine_line, markdown_table, output_folder, save_figure,
                               save_text, timed)



def psf_support():
    from poevp_optics.sources import spectra
    from poevp_optics.camera.relay import airy_psf, convolve

    resp = spectra.sensor_response_e_per_J(spectra.load_spectrum("file:spectra/imx253_mono_qe.csv", emissive=True))
    img = np.full((368, 640), 1.0)
    img[170:200, 300:340] = 1e6
    ref_psf = airy_psf(8.0, 3.45e-6, spectra.WAVELENGTHS_NM, resp, support_px=513)
    ref = convolve(img, ref_psf)
    rows = []
    for e in (0.9, 0.99, 0.999, 0.9999):
        psf = airy_psf(8.0, 3.45e-6, spectra.WAVELENGTHS_NM, resp, energy=e)
        t, out = timed(lambda: convolve(img, psf), 3)
        rows.append([f"{e:.4%}", psf.kernel.shape[0], psf.truncation_error,
                     float(np.abs(out - ref).sum() / ref.sum()), t * 1e3])
    return rows


def float_precision():
    from poevp_optics.camera.camera import Camera
    from poevp_optics.camera.dmd import transmission_table
    from poevp_optics.scene.load import load_scene
    from poevp_optics.camera.sensor import NoiseSwitches

    spec = load_scene("scenes/highbeam_plate", ["render.subframes=8"])
    cam = Camera.from_params(spec.resolved.camera, NoiseSwitches.off())
    rng = np.random.default_rng(0)
    subs = [rng.uniform(1e12, 1e18, cam.mirror_shape).astype(np.float32) for _ in range(8)]
    mask = rng.integers(0, 256, cam.mirror_shape).astype(np.float64)
    t32, cap = timed(lambda: cam.capture(subs, mask, 0, 1), 3)
    table = transmission_table(np.arange(256), spec.dmd, cam.schedule(0), 8)

    def ref64():
        w = table[mask.astype(int)]
        return np.einsum("hwk,khw->hw", w, np.stack(subs).astype(np.float64)) * cam.electrons_per_radiance()

    t64, ref = timed(ref64, 3)
    err = np.abs(cap.signal_e.astype(np.float64) / ref - 1)
    return [["DrJit float32 chain (DMD + sensor, noise off)", float(np.max(err)), float(np.median(err)), t32 * 1e3],
            ["NumPy float64 reference (DMD weights x sub-frames)", 0.0, 0.0, t64 * 1e3]]


def poisson_methods():
    from scipy.stats import poisson as sp_poisson

    import drjit as dr
    from drjit.auto import PCG32, Float, UInt32

    from poevp_optics.camera.sensor import poisson

    n = 1_000_000
    rows = []
    rng = np.random.default_rng(0)
    for lam in (0.5, 3.0, 30.0, 3e4):
        def ours():
            r = PCG32(size=n, initstate=dr.opaque(UInt32, 7), initseq=dr.arange(UInt32, n))
            k, _ = poisson(dr.full(Float, lam, n), r)
            dr.eval(k)
            return np.array(k)

        def gauss():
            return np.maximum(np.rint(lam + np.sqrt(lam) * rng.standard_normal(n)), 0)

        def numpy_exact():
            return rng.poisson(lam, n).astype(np.float64)

        for name, fn in (("ours (Knuth < 10, PTRS)", ours), ("Gaussian approximation", gauss),
                         ("NumPy poisson", numpy_exact)):
            t, x = timed(fn, 3)
            ks = np.arange(int(max(0, lam - 8 * np.sqrt(lam) - 5)), int(lam + 8 * np.sqrt(lam) + 6))
            emp = np.searchsorted(np.sort(x), ks, side="right") / n
            dist = float(np.max(np.abs(emp - sp_poisson.cdf(ks, lam))))
            rows.append([lam, name, dist, t * 1e3])
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_results_flag(ap)
    dest = output_folder(ap.parse_args(argv).results)
    from poevp_optics.core import runtime

    runtime.set_threads(2)
    psf = psf_support()
    fp = float_precision()
    po = poisson_methods()
    text = "\n".join([
        f"# Work-precision of the camera's accuracy settings\n\nMachine: {machine_line()}. Medians of 3.\n",
        "## Relay PSF support (Airy f/8, 368x640, 1e6:1 highlight)\n",
        markdown_table(["energy held", "support px", "truncated energy", "rel. L1 error vs 513 px", "ms"], psf), "",
        "## float32 chain vs float64 reference (368x640, K = 8)\n",
        markdown_table(["path", "max rel. error", "median rel. error", "ms"], fp), "",
        "## Poisson samplers (1e6 draws; Kolmogorov distance to the exact CDF; the sampling "
        "noise floor of 1e6 draws is ~1e-3)\n",
        markdown_table(["lambda", "method", "KS distance", "ms"], po), ""])
    print(text)
    save_text(dest / "work_precision.md", text)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    axes[0].loglog([r[4] for r in psf], [r[3] for r in psf], "o-")
    for r in psf:
        axes[0].annotate(r[0], (r[4], r[3]), fontsize=7)
    axes[0].set(xlabel="convolution ms", ylabel="relative L1 error", title="PSF support")
    for name in ("ours (Knuth < 10, PTRS)", "Gaussian approximation", "NumPy poisson"):
        sel = [r for r in po if r[1] == name]
        axes[1].loglog([r[3] for r in sel], [max(r[2], 1e-5) for r in sel], "o-", label=name)
    axes[1].set(xlabel="ms per 1e6 draws", ylabel="KS distance", title="Poisson samplers (lambda 0.5 ... 3e4)")
    axes[1].legend(fontsize=7)
    print("wrote", save_figure(fig, dest / "work_precision.png"))


if __name__ == "__main__":
    main()
