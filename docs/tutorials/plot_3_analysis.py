"""
Testing analysis code
=====================

Analysis code — a reduction from raw images to BRDF samples, a fit, an estimator of your
own — is only trustworthy once it has been run on data whose answer is known. gonio renders
the raw images a real LBL imaging gonioreflectometer would write, each with the JSON side-car
holding what a real instrument records, from a material whose true BRDF you choose. You
reduce them (with gonio's reduction or your own code), fit, and compare with the truth.

This tutorial renders the sample, the diffuse standard and the background at two incidence
angles, writes and reads them as files, reduces them with :mod:`gonio.calibration.reduce`,
fits the Ward model, tests a small estimator of its own against the truth, and plots the
measured samples in the plane of incidence against the fitted and the true model.
"""

# %%
# Render raw images with their side-cars
# --------------------------------------
# :class:`~gonio.simulator.lbl.LBLInstrument` is the simulated instrument (ellipsoidal dome of
# radius 0.15 m, source-sample half-separation 0.01 m, equidistant fisheye). A smaller sensor
# than the default 640 × 480 keeps this tutorial quick. ``bracket`` chooses the f-stops that
# cover the dynamic range of the scene and returns one ``(image, metadata)`` pair per stop;
# :func:`gonio.io.images.write_image` writes the 16-bit image and its side-car
# (``image.png.json``) atomically.
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from gonio.calibration.reduce import load_capture, reduce_capture
from gonio.simulator import LBLInstrument

from gonio import fit, materials
from gonio.io.images import read_image, sidecar_path, write_image
from gonio.samples import BRDFSamples

inst = LBLInstrument(
    "ellipsoid", radius=0.15, half_separation=0.01, lens="equidistant", width=320, height=240
)
folder = Path(tempfile.mkdtemp(prefix="gonio-raw-"))
scenes = {"sample": "rolled_brass", "standard": "standard", "background": None}
files: dict[float, dict[str, list[Path]]] = {}
for k, deg in enumerate((20.0, 45.0)):
    files[deg] = {}
    for j, (what, scene) in enumerate(scenes.items()):
        shots = inst.bracket(scene, np.radians(deg), rng=10 * k + j)
        files[deg][what] = []
        for n, (img, meta) in enumerate(shots):
            path = folder / f"theta{deg:.0f}_{what}_{n}.png"
            write_image(path, img, meta)
            files[deg][what].append(path)
print(sorted(p.name for p in folder.iterdir()))

# %%
# A reduction sees only the files. The side-car carries the instrument state a laboratory
# records — dome, lens, sensor settings, exposure, f-number, incidence angles — and, under
# ``brdf``, what the simulator rendered: that is the truth, which a reduction must not read.
img, meta = read_image(files[45.0]["sample"][0])
print(sidecar_path(files[45.0]["sample"][0]).name, "->", sorted(meta))
print("exposure", meta["exposure_s"], "s, f/", meta["f_number"], ", theta_i", meta["theta_i"])

# %%
# Reduce them
# -----------
# :func:`~gonio.calibration.reduce.load_capture` reads a bracket back;
# :func:`~gonio.calibration.reduce.reduce_capture` merges the exposures, applies Ward's
# eq. 2 (sample over standard, background removed), recovers each pixel's reflected
# direction with eq. 3 and thins the pixels to samples. Your own reduction would take the
# same files and return a :class:`~gonio.samples.BRDFSamples` table (columns ``theta_i,
# phi_i, theta_o, phi_o, value, sigma``) to go on with.
tables = []
for deg, f in files.items():
    r = reduce_capture(
        load_capture(f["sample"]), load_capture(f["standard"]), load_capture(f["background"])
    )
    print(f"θi = {deg:.0f}°: {r.stats['n_before']} pixels -> {r.stats['n_after']} samples")
    tables.append(r.samples)
samples = BRDFSamples.concatenate(tables)

# %%
# Fit and compare with the truth
# ------------------------------
# :func:`gonio.fit.fit <gonio.fit.core.fit>` fits any registered model or sum of models; the
# truth is the preset, :func:`gonio.materials.get`. The comparison is the test of the whole
# chain: the error of every parameter should be consistent with its standard error.
result = fit.fit(samples, "ward")
truth = materials.get("rolled_brass")
print(f"converged {result.converged}, chi2/dof {result.chi2_dof:.3f}, n = {result.n_samples}")
for name, true_value in truth.params.items():
    est, se = result.params[name], result.stderr[name]
    pull = (est - true_value) / se
    print(f"{name:8s} truth {true_value:.4f}  fit {est:.5f} ± {se:.1e}  pull {pull:+.2f}")

# %%
# Test an estimator of your own
# -----------------------------
# Suppose your analysis estimates the diffuse reflectance ρd from the samples far from the
# specular peak, where the Ward lobe has decayed: π times the median BRDF there. Rendered
# data tell you how biased that shortcut is before you trust it on real measurements.
wi, wo = samples.wi, samples.wo
h = wi + wo
h /= np.linalg.norm(h, axis=-1, keepdims=True)
far = h[:, 2] < np.cos(np.radians(40.0))  # half-vector more than 40° from the normal
rho_d_own = np.pi * np.median(samples.value[far])
print(f"own estimate of rho_d: {rho_d_own:.5f} from {far.sum()} samples")
print(f"truth: {truth.params['rho_d']}")

# %%
# The figure: one raw frame as the camera saw it, and the samples near the plane of
# incidence (within 3° of it) at each angle against the fitted and the true Ward model.
fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(11, 4))
im = ax0.imshow(np.log10(np.maximum(img, 1)), cmap="magma")
ax0.set_title(f"raw frame, θi = 45° (f/{meta['f_number']:g}), log10 DN")
ax0.axis("off")
fig.colorbar(im, ax=ax0, shrink=0.8)
for deg, table, colour in zip(files, tables, ("C0", "C1")):
    phi = np.angle(np.exp(1j * (table.phi_o - table.phi_i)))
    near = np.minimum(np.abs(phi), np.pi - np.abs(phi)) < np.radians(3.0)
    signed = np.where(np.abs(phi[near]) > np.pi / 2, 1.0, -1.0) * table.theta_o[near]
    ax1.errorbar(np.degrees(signed), table.value[near], table.sigma[near], fmt=".", ms=3,
                 color=colour, alpha=0.5, label=f"samples, θi = {deg:.0f}°")  # fmt: skip
    t = np.radians(np.linspace(-85, 85, 341))
    wi_ = np.array([np.sin(np.radians(deg)), 0.0, np.cos(np.radians(deg))])
    wo_ = np.stack([-np.sin(t), np.zeros_like(t), np.cos(t)], axis=-1)
    ax1.plot(np.degrees(t), result.model(wi_, wo_), color=colour, lw=1.2)
    ax1.plot(np.degrees(t), truth(wi_, wo_), "k:", lw=1.0)
ax1.set(yscale="log", xlabel="θo in the plane of incidence (deg, + = forward)",
        ylabel="BRDF (1/sr)", title="samples, fit (solid), truth (dotted)")  # fmt: skip
ax1.legend(fontsize=8)
fig.tight_layout()
