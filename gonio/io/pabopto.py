"""Sample tables as PAB-Opto measurement files, and Radiance BSDFs built from them.

LBNL's goniophotometer workflow carries measured BRDFs into Radiance as PAB-Opto ("Mountain")
files, one per incident direction, converted by ``pabopto2bsdf`` into a scattering
interpolant (SIR) and by ``bsdf2klems`` or ``bsdf2ttree`` into BSDF XML for Radiance's
``BSDF`` material. :func:`write_pabopto` writes the files; :func:`build_bsdf` runs the
tools (when installed: ``pip install 'gonio[radiance]'``) and ``checkBSDF``;
:func:`build_model_bsdf` builds the same XML from a fitted model's exact ``.cal`` instead
(``bsdf2klems -f`` / ``bsdf2ttree -f``), which needs no symmetry and no interpolation.
:func:`klems_hemispherical` reads a Klems XML's hemispherical reflectance per incident patch.

File format (``pabopto2bsdf(1)`` and ``src/cv/pabopto2bsdf.c`` of Radiance 6.0)
--------------------------------------------------------------------------------
Each file starts with ``#`` header lines::

    #sample_name "rolled_brass"
    #format: theta phi BRDF
    #intheta 30
    #inphi 90
    #upphi 90
    #colorimetry: CIE-Y

followed by one line ``theta_o phi_o value`` per sample (degrees, sr⁻¹). Angles are in the
sample frame: θ from the normal, φ counter-clockwise seen from the front, which is gonio's
frame (φ from +x towards +y); ``intheta``/``inphi`` is the direction towards the source, as
gonio's ``wi`` (pabopto2bsdf puts the mirror peak at ``(−x, −y, z)`` of it). ``#upphi 90``
keeps gonio's axes as Radiance's standard BSDF axes (φ = 0 the sample's x, φ = 90° its
"up" y axis), so the ``BSDF`` primitive takes the sample's y axis as its up vector.

Symmetry (what pabopto2bsdf infers, and what gonio checks before writing)
-------------------------------------------------------------------------
pabopto2bsdf infers the BSDF's symmetry from the incident azimuths (``bsdfrep.c``,
``new_input_direction``): incidences within 1° of the normal are ignored; an azimuth counts
for a quadrant only if it lies *strictly inside* it (1° < φ < 89°, 91° < φ < 179°, …). One
azimuth for every incidence means isotropic; azimuths inside one quadrant mean
quadrilateral symmetry (the sample mirror-symmetric about x and y, as rolled or brushed
metal, whose Ward α_x, α_y axes are x and y); two adjacent quadrants bilateral (or "up",
which must be asked for); all four anisotropic. Several azimuths that all lie on quadrant
boundaries — rotations 0° and 90° of an anisotropic sample, Ward's protocol — form
no valid symmetry: pabopto2bsdf builds a broken interpolant ("41 incident directions but
only 1 interpolant") that bsdf2ttree cannot use. :func:`pabopto_symmetry` reproduces the
rule and :func:`write_pabopto` refuses such a set before writing anything, naming the
rotation to add: for the mirror-symmetric sample a researcher means by measuring 0° and 90°,
one azimuth strictly inside the quadrant (45°) gives quadrilateral symmetry, which is what
they would expect; gonio does not invent data at an azimuth it did not measure. The LBL
campaign's default rotations for an anisotropic sample are therefore 0°, 45° and 90°.

Run time (what makes the measured route slow, and how gonio bounds it)
----------------------------------------------------------------------
pabopto2bsdf (``bsdfrbf.c``) gathers each file's points into a 256 × 256 grid of equal
solid angle (the concentric map of ``(x, y)/sqrt(1 + z)``) and builds a quadtree over it:
a region is split while all four quarters hold points, and four leaves merge into one
Gaussian lobe only where a plane fits their values (mean squared error below 5e-5, or
5e-4 relative). A campaign's single-pixel samples carry a few per cent of noise (7 % in
the default campaign's diffuse floor), which defeats the merge, so the lobes per incident
direction grow with its points. It then
builds a transport plan between the lobes of every pair of neighbouring incident
directions (``bsdfmesh.c``, an ``n_a × n_b`` matrix each), and bsdf2ttree
(``bsdf2ttree.c``) evaluates, for each of its ``2^g × 2^g`` incident directions, an
interpolated distribution of up to ``-l`` (15000) lobes at ``2^g × 2^g`` exiting
directions (64 super-samples where neighbours differ by more than 35 %). Time grows with
the lobes per direction (the points per file) and with ``16^g``. A laboratory's PAB-Opto
files hold a few thousand points per incident direction; the default campaign's table
(rolled brass, 21 θi × rotations 0°, 45°, 90°: 61 directions, 173,406 samples) holds 1,323
to 10,070 per direction; with rotations 0°, 30°, 60°, 90° (81 directions, 179,926 samples)
pabopto2bsdf took 31 minutes and bsdf2ttree had not finished after 54.
:func:`pabopto_files` therefore averages each direction's samples in ``cells × cells`` of
those equal-solid-angle cells (:func:`bin_directions`), splitting a cell whose values differ
by more than ``spread`` (a lobe, not noise) down to pabopto2bsdf's own cells, so the peak
keeps its points and the flat floor is averaged, where the quadtree can then merge (default
16 cells and spread 2: 366 to 710 points per direction; 32 cells, 1,026 to 1,363, cost the
same). The measured build times and errors are in :func:`build_bsdf` and
``benchmarks/bench_bsdf.py``.

References
----------
.. [Radiance] G. J. Ward et al., Radiance 6.0 (LBNL): ``pabopto2bsdf(1)``,
   ``bsdf2klems(1)``, ``bsdf2ttree(1)`` manual pages; ``src/cv/pabopto2bsdf.c``
   (header keywords), ``src/cv/bsdfrep.c`` (``new_input_direction``: the symmetry rule,
   ``def_rbf_spec``: the mirror direction; ``pos_from_vec``: the grid), ``src/cv/bsdfrbf.c``
   (the lobes), ``src/cv/bsdfmesh.c`` (the transport plans), ``src/cv/bsdfinterp.c``
   (``advect_rbf``), ``src/cv/bsdf2ttree.c``.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gonio.hints import keyword
from gonio.io.atomic import atomic_write_bytes
from gonio.samples import BRDFSamples

__all__ = [
    "DEFAULT_CELLS",
    "SYMMETRIES",
    "BSDFBuild",
    "bin_directions",
    "build_bsdf",
    "build_model_bsdf",
    "incidences",
    "klems_hemispherical",
    "pabopto_files",
    "pabopto_symmetry",
    "parse_check_bsdf",
    "write_pabopto",
]

#: pabopto2bsdf's symmetry codes (its ``quadrant_sym`` table) by quadrant-coverage bit mask
_QUADRANT_SYM = "IQQBQ?B?QB??B??A"  # index = QUAD1 | QUAD2<<1 | QUAD3<<2 | QUAD4<<3
SYMMETRIES = {"I": "isotropic", "Q": "quadrilateral", "B": "bilateral", "A": "anisotropic"}
_NAME = re.compile(r"^[A-Za-z0-9_.\-]+$")
_CELLS = (8, 16, 32, 64, 128, 256)
_GRIDRES = 256  # pabopto2bsdf's grid (bsdfrep.h, GRIDRES)
#: cells per side of the averaging grid of :func:`pabopto_files` (chosen from the measured
#: build time against error in the module docstring)
DEFAULT_CELLS = 16
#: :func:`bin_directions`'s ``spread`` of :func:`pabopto_files`
DEFAULT_SPREAD = 2.0
#: ``bsdf2ttree -l`` of :func:`build_bsdf` (Radiance's default)
DEFAULT_MAX_LOBES = 15000
#: ``bsdf2klems -n`` of :func:`build_bsdf` (samples per Klems patch pair; measured in
#: :func:`build_bsdf`: Radiance's 1024 took 160 processor seconds, 128 takes 22 with the
#: same error against the fit)
DEFAULT_SAMPLES_PER_PATCH = 128
#: processor seconds of ``pabopto2bsdf`` per incident direction (the default campaign's 61
#: directions at the default cells and spread: 60.7 s, 31.0 s of wall time on two processes,
#: idle 2-core machine), for the estimate it prints
_SECONDS_PER_DIRECTION = 1.0
#: processor seconds of ``bsdf2klems`` per sample per patch pair for the same table (24.5 s
#: at ``-n 128``, idle machine), for the estimate printed before its own progress bar takes
#: over
_KLEMS_SECONDS_PER_SAMPLE = 0.19


def incidences(samples: BRDFSamples) -> list[tuple[float, float, np.ndarray]]:
    """``(theta_i_deg, phi_i_deg, row_indices)`` per distinct incident direction.

    Directions are distinct at 1e-6°; normal incidences (θi < 1e-6°) are one direction
    (their azimuth is meaningless; written as 0). Sorted by θi, then φi.
    """
    ti = np.degrees(samples.theta_i)
    pi = np.mod(np.degrees(samples.phi_i), 360.0)
    normal = ti < 1e-6
    pi = np.where(normal, 0.0, pi)
    key = np.stack([np.round(ti, 6), np.round(pi, 6) % 360.0], axis=1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    out = []
    for k, (t, p) in enumerate(uniq):
        out.append((float(t), float(p), np.flatnonzero(inv == k)))
    return out


def _disk2square(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shirley-Chiu concentric map of the unit disk onto the unit square (Radiance's
    ``disk2square``, ``src/common/disk2square.c``)."""
    r = np.hypot(x, y)
    phi = np.arctan2(y, x)
    phi = np.where(phi < -math.pi / 4, phi + 2 * math.pi, phi)
    q = math.pi / 4
    reg = np.clip(np.floor((phi + q) / (2 * q)), 0, 3).astype(int)
    a = np.choose(reg, [r, -(phi - math.pi / 2) * r / q, -r, -(phi - 1.5 * math.pi) * -r / q])
    b = np.choose(reg, [phi * r / q, r, (phi - math.pi) * -r / q, -r])
    return a * 0.5 + 0.5, b * 0.5 + 0.5


def bin_directions(
    theta_o: np.ndarray,
    phi_o: np.ndarray,
    value: np.ndarray,
    cells: int,
    spread: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Average samples of one incident direction in ``cells × cells`` equal-solid-angle cells.

    The cells are those of pabopto2bsdf's own ``GRIDRES`` × ``GRIDRES`` grid (256) at a
    coarser resolution: the exiting direction ``(x, y, z)`` maps to the disk point
    ``(x, y) / sqrt(1 + z)`` (equal area) and through Shirley and Chiu's concentric map to
    the square (``bsdfrep.c``, ``pos_from_vec``), so with ``cells`` a power of two up to
    256 each cell is a union of pabopto2bsdf's cells. Each occupied cell gives one point:
    the normalised mean of its unit vectors and the mean of its values.

    With ``spread``, a cell whose largest value exceeds ``spread`` times its smallest (a
    lobe, not noise about a smooth floor) is split into four, down to pabopto2bsdf's own
    cells, so the points stay as dense as measured where the BRDF changes fast (the
    specular peak) and are averaged where it is flat. pabopto2bsdf sizes each Gaussian
    lobe by the cell it stands for, so this keeps the peak's lobes narrow.

    Parameters
    ----------
    theta_o, phi_o : array
        Exiting directions (radians).
    value : array
        BRDF values (sr⁻¹).
    cells : int
        Cells per side of the square (the coarsest level).
    spread : float, optional
        Largest ratio of values averaged in one cell (above 1); ``None``: no splitting.

    Returns
    -------
    theta_o, phi_o, value, count : arrays
        One entry per occupied cell (radians, sr⁻¹, samples averaged).

    References
    ----------
    .. [SC1997] P. Shirley and K. Chiu, "A low distortion map between disk and square",
       Journal of Graphics Tools 2(3), 45-52, 1997. https://doi.org/10.1080/10867651.1997.10487479
    """
    st = np.sin(theta_o)
    v = np.stack([st * np.cos(phi_o), st * np.sin(phi_o), np.cos(theta_o)], axis=-1)
    norm = 1.0 / np.sqrt(1.0 + np.abs(v[:, 2]))
    sx, sy = _disk2square(v[:, 0] * norm, v[:, 1] * norm)
    key = np.empty(value.size, dtype=np.int64)
    todo = np.arange(value.size)
    level, c = 0, cells
    while todo.size:
        ix = np.clip((sx[todo] * c).astype(np.int64), 0, c - 1)
        k = ix * c + np.clip((sy[todo] * c).astype(np.int64), 0, c - 1)
        done = np.ones(todo.size, dtype=bool)
        if spread is not None and c < _GRIDRES:
            u, inv = np.unique(k, return_inverse=True)
            hi, lo = np.full(u.size, -np.inf), np.full(u.size, np.inf)
            np.maximum.at(hi, inv.ravel(), value[todo])
            np.minimum.at(lo, inv.ravel(), value[todo])
            done = (hi <= spread * lo)[inv.ravel()]
        key[todo[done]] = level * _GRIDRES * _GRIDRES + k[done]
        todo, level, c = todo[~done], level + 1, 2 * c
    uniq, inv, count = np.unique(key, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    mean = np.stack([np.bincount(inv, v[:, k], uniq.size) for k in range(3)], axis=-1)
    mean /= np.linalg.norm(mean, axis=-1, keepdims=True)
    val = np.bincount(inv, value, uniq.size) / count
    theta = np.arccos(np.clip(mean[:, 2], -1.0, 1.0))
    phi = np.mod(np.arctan2(mean[:, 1], mean[:, 0]), 2 * math.pi)
    return theta, phi, val, count


def pabopto_symmetry(theta_phi_deg: Sequence[tuple[float, float]]) -> str:
    """The symmetry pabopto2bsdf infers from incident ``(θ, φ)`` in degrees (``upphi`` 90).

    Returns ``"I"``, ``"Q"``, ``"B"`` or ``"A"`` (:data:`SYMMETRIES`).

    Raises
    ------
    ValueError
        The azimuths form no valid symmetry (several azimuths all on quadrant boundaries,
        or an illegal quadrant combination); the message names the rotations to add.
    """
    single = None
    ref_phi = None
    mask = 0
    phis = set()
    for theta, phi in theta_phi_deg:
        if theta < 1.0:  # pabopto2bsdf: "don't rely on phi near normal"
            continue
        phi = float(phi) % 360.0
        phis.add(round(phi, 6))
        if single is None:
            single = True
        elif single:
            single = round(phi) == round(ref_phi)
        ref_phi = phi
        for q in range(4):
            if 90.0 * q + 1.0 < phi < 90.0 * q + 89.0:
                mask |= 1 << q
    shown = ", ".join(f"{p:g}" for p in sorted(phis))
    if single or single is None:
        return "I"
    sym = _QUADRANT_SYM[mask]
    if mask == 0:
        raise ValueError(
            f"incident azimuths {{{shown}}} deg all lie on quadrant boundaries (within 1 deg of "
            "0, 90, 180, 270): pabopto2bsdf infers a BSDF's symmetry from azimuths strictly "
            "inside a quadrant and builds no valid interpolant from these. For a sample "
            "mirror-symmetric about its x and y axes (rolled or brushed metal) add one "
            "rotation inside (1, 89) deg, e.g. rotations 0, 45, 90 (quadrilateral symmetry; "
            "gonio campaign --rotations 0,45,90); for an isotropic sample export a single "
            "azimuth"
        )
    if sym == "?":
        raise ValueError(
            f"incident azimuths {{{shown}}} deg cover quadrants that form no symmetry "
            "pabopto2bsdf accepts (one quadrant: quadrilateral; two adjacent: bilateral; "
            "all four: anisotropic); add rotations to complete adjacent quadrants"
        )
    return sym


def pabopto_files(
    samples: BRDFSamples,
    sample_name: str = "gonio",
    negative: str = "error",
    cells: int | None = DEFAULT_CELLS,
    spread: float | None = DEFAULT_SPREAD,
) -> dict[str, str]:
    """File name → PAB-Opto text, one file per incident direction (see the module docstring).

    Parameters
    ----------
    samples : BRDFSamples
        A grey sample table (values in sr⁻¹) with at least two incident directions.
    sample_name : str
        ``#sample_name`` (no double quote).
    negative : {"error", "clip", "drop"}
        Values below 0 (noise in a dark region): refused (default), clipped to 0, or dropped.
    cells : int or None
        Average each incident direction's samples in ``cells × cells`` equal-solid-angle
        cells (:func:`bin_directions`; a power of two, 8..256) before writing, which bounds
        the points per file and so pabopto2bsdf's and bsdf2ttree's run time (see the module
        docstring, "Run time"); ``None`` writes every sample.
    spread : float or None
        :func:`bin_directions`'s ``spread``: cells whose values differ by more than this
        factor are split (down to pabopto2bsdf's own cells), keeping the peak's points.

    Raises
    ------
    ValueError
        Fewer than two incident directions, a spectral table, negative values (with
        ``negative="error"``), an incident direction without samples, or azimuths without
        a symmetry pabopto2bsdf accepts (:func:`pabopto_symmetry`).
    """
    if not isinstance(samples, BRDFSamples):
        raise ValueError(f"samples must be a BRDFSamples table, got {type(samples).__name__}")
    if samples.wavelength_nm is not None:
        raise ValueError(
            "samples is spectral; PAB-Opto files hold one photometric value (CIE-Y) per "
            "direction: export a grey table (one band)"
        )
    if negative not in ("error", "clip", "drop"):
        raise ValueError(f"negative {negative!r}; expected 'error', 'clip' or 'drop'")
    if cells is not None and (
        not isinstance(cells, int) or isinstance(cells, bool) or cells not in _CELLS
    ):
        raise ValueError(f"cells {cells!r}; expected None or a power of two in 8..256")
    if spread is not None and not (isinstance(spread, int | float) and spread > 1.0):
        raise ValueError(f"spread {spread!r}; expected None or a number above 1")
    if not isinstance(sample_name, str) or '"' in sample_name or "\n" in sample_name:
        raise ValueError(f"sample_name {sample_name!r} must be one line without double quotes")
    value = samples.value
    bad = value < 0.0
    if bad.any() and negative == "error":
        raise ValueError(
            f"samples has {int(bad.sum())} values below 0 (min {float(value.min()):.3g} sr^-1); "
            f"a BRDF cannot be negative: pass {keyword('negative', 'clip', 'drop')} to export "
            "noisy data"
        )
    inc = incidences(samples)
    if len(inc) < 2:
        raise ValueError(
            f"samples has {len(inc)} incident direction(s); pabopto2bsdf needs at least two"
        )
    pabopto_symmetry([(t, p) for t, p, _ in inc])
    to = np.degrees(samples.theta_o)
    po = np.mod(np.degrees(samples.phi_o), 360.0)
    files: dict[str, str] = {}
    for t, p, rows in inc:
        v = value[rows]
        if negative == "clip":
            v = np.maximum(v, 0.0)
        keep = v >= 0.0
        if not keep.any():
            raise ValueError(f"incident direction theta {t:g}, phi {p:g} deg has no samples")
        a, b, v = to[rows][keep], po[rows][keep], v[keep]
        if cells is not None:
            a, b, v, _ = bin_directions(np.radians(a), np.radians(b), v, cells, spread)
            a, b = np.degrees(a), np.degrees(b)
        head = (
            f'#sample_name "{sample_name}"\n#format: theta phi BRDF\n#intheta {t:.6f}\n'
            f"#inphi {p:.6f}\n#upphi 90\n#colorimetry: CIE-Y\n"
        )
        body = "".join(f"{x:.6f} {y:.6f} {z:.9g}\n" for x, y, z in zip(a, b, v))
        files[f"{sample_name}_t{t:07.3f}_p{p:07.3f}.dat"] = head + body
    return files


def write_pabopto(
    samples: BRDFSamples,
    folder: str | os.PathLike,
    sample_name: str = "gonio",
    negative: str = "error",
    cells: int | None = DEFAULT_CELLS,
    spread: float | None = DEFAULT_SPREAD,
) -> list[Path]:
    """Write :func:`pabopto_files` into ``folder`` (created if missing); the paths written.

    Everything is checked and formatted before the first file is written; each file is
    written atomically, and if writing one fails the files already written are removed, so
    the folder never holds a partial set.
    """
    if not isinstance(sample_name, str) or not _NAME.match(sample_name):
        raise ValueError(f"sample_name {sample_name!r} must be a word (letters, digits, _ . -)")
    files = pabopto_files(samples, sample_name, negative, cells, spread)
    folder = Path(folder)
    existing = next((p for p in (folder, *folder.parents) if p.exists()), Path("."))
    if existing.is_dir() and not os.access(existing, os.W_OK | os.X_OK):
        raise ValueError(f"folder {str(existing)!r} is not writable")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"folder {str(folder)!r} cannot be created: {exc}") from None
    written: list[Path] = []
    try:
        for name, text in files.items():
            written.append(atomic_write_bytes(folder / name, text.encode("ascii")))
    except OSError:
        for p in written:
            p.unlink(missing_ok=True)
        raise
    return written


@dataclass
class BSDFBuild:
    """What a BSDF build made: the XML, the ``BSDF`` primitive, checkBSDF's report.

    ``check`` is checkBSDF's text; ``components`` its table per component (``"Interior
    Refl"`` is the front reflection): ``lambertian`` (XYZ, fractions), ``max_total`` (the
    largest directional-hemispherical reflectance over incidences, a fraction) and
    ``reciprocity_error`` (min, mean, max, fractions). ``seconds`` times each program: wall
    time under its name, processor time under ``<name>_cpu``.
    """

    xml: Path
    rad: Path
    kind: str
    symmetry: str
    seconds: dict[str, float] = field(default_factory=dict)
    check: str = ""
    components: dict[str, dict[str, Any]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (paths as strings)."""
        return {
            "xml": str(self.xml),
            "rad": str(self.rad),
            "kind": self.kind,
            "symmetry": SYMMETRIES.get(self.symmetry, self.symmetry),
            "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
            "components": self.components,
        }


_COMPONENTS = ("Interior Refl", "Exterior Refl", "Int->Ext Trans", "Ext->Int Trans")


def parse_check_bsdf(text: str) -> dict[str, dict[str, Any]]:
    """checkBSDF's component table: see :class:`BSDFBuild` (``components``)."""
    out: dict[str, dict[str, Any]] = {}
    recip = False
    for line in text.splitlines():
        if line.startswith("Component") and "Reciprocity" in line:
            recip = True
            continue
        name = next((c for c in (*_COMPONENTS, "Transmission") if line.startswith(c)), None)
        if name is None:
            continue
        nums = [float(x) for x in re.findall(r"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?", line)]
        entry = out.setdefault(name, {})
        if recip and len(nums) >= 3:
            entry["reciprocity_error"] = [x / 100.0 for x in nums[-3:]]
        elif not recip and len(nums) >= 5:
            entry["lambertian"] = [x / 100.0 for x in nums[:3]]
            entry["max_total"] = nums[3] / 100.0
            entry["min_angle_deg"] = nums[4]
    return out


def klems_hemispherical(xml_path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Directional-hemispherical reflectance of each incident Klems patch of a Klems XML.

    ``R_i = Σ_j f_ji Λ_j``: the matrix rows are exiting patches (``IncidentDataStructure``
    ``Columns``), ``Λ_j = π (sin² θ_hi − sin² θ_lo) / n_φ`` the projected solid angle of
    exiting patch ``j`` of its ring. Returns ``{"theta_deg", "phi_deg"}`` (patch centres)
    and one array per ``WavelengthDataDirection`` (e.g. ``"Reflection Back"``, Radiance's
    front side).
    """
    import xml.etree.ElementTree as ET

    ns = {"w": "http://windows.lbl.gov"}
    root = ET.parse(xml_path).getroot()
    basis = root.find(".//w:AngleBasis", ns)
    if basis is None:
        raise ValueError(f"{xml_path}: no Klems AngleBasis (not a Klems BSDF)")
    lam, theta, phi = [], [], []
    for b in basis.findall("w:AngleBasisBlock", ns):
        th = float(b.findtext("w:Theta", namespaces=ns))
        n = int(b.findtext("w:nPhis", namespaces=ns))
        lo = math.radians(float(b.findtext("w:ThetaBounds/w:LowerTheta", namespaces=ns)))
        hi = math.radians(float(b.findtext("w:ThetaBounds/w:UpperTheta", namespaces=ns)))
        lam += [math.pi * (math.sin(hi) ** 2 - math.sin(lo) ** 2) / n] * n
        theta += [th] * n
        phi += [360.0 * k / n for k in range(n)]
    out: dict[str, np.ndarray] = {"theta_deg": np.array(theta), "phi_deg": np.array(phi)}
    n = len(lam)
    for blk in root.findall(".//w:WavelengthDataBlock", ns):
        direction = blk.findtext("w:WavelengthDataDirection", namespaces=ns)
        vals = np.array(blk.findtext("w:ScatteringData", namespaces=ns).replace(",", " ").split())
        f = vals.astype(np.float64).reshape(n, n)
        out[direction] = f.T @ np.array(lam)
    return out


def _check_up(up: Sequence[float]) -> list[float]:
    upv = [float(x) for x in up]
    if len(upv) != 3 or not any(upv) or not all(math.isfinite(x) for x in upv):
        raise ValueError(f"up must be a non-zero 3-vector, got {up!r}")
    return upv


def _check_int(name: str, v: Any, lo: int, hi: int) -> None:
    if not (isinstance(v, int) and not isinstance(v, bool) and lo <= v <= hi):
        raise ValueError(f"{name} {v!r}; expected an integer in {lo}..{hi}")


def _converter(kind: str, samples_per_patch: int, resolution: int, reciprocity: bool) -> list:
    """The bsdf2klems / bsdf2ttree command (options checked; their progress bar left on:
    ``-p`` would turn it off)."""
    _check_int("samples_per_patch", samples_per_patch, 1, 1 << 20)
    _check_int("resolution", resolution, 4, 7)
    if kind == "klems":
        return ["bsdf2klems", "-n", samples_per_patch]
    if kind == "ttree":
        return ["bsdf2ttree", "+a" if reciprocity else "-a", "-g", resolution]
    raise ValueError(f"kind {kind!r}; expected 'klems' or 'ttree'")


#: a progress callback: one line of text (what runs, how far, the estimate)
Progress = Callable[[str], None]


def _bar_fraction(text: str) -> float | None:
    """The fraction done shown by the last complete progress bar in ``text``, or ``None``.

    bsdf2klems and bsdf2ttree draw it on stderr as ``\\r``, then a ``*`` for each part done,
    a spinner character (``-\\|/``) and a ``-`` for each part to do (79 characters).
    """
    for bar in reversed(text.split("\r")[1:-1]):
        if _is_bar(bar):
            return bar.count("*") / (len(bar) - 1)
    return None


def _is_bar(text: str) -> bool:
    return len(text) > 10 and set(text) <= set("*-\\|/")


def _run_reporting(
    args: list, cwd: Any, timeout: float, progress: Progress | None, estimate: float
) -> bytes:
    """Run Radiance program ``args[0]`` (as :func:`~gonio.io.radiance.run_tool`: its
    stdout, ``RuntimeError`` on a non-zero exit, killed at ``timeout`` seconds), telling
    ``progress`` how far it is: from its own progress bar when it draws one (an estimate of
    the time left from the time so far), else its time so far against ``estimate``
    (its seconds on an idle machine), at most every 10 % or 15 s."""
    import subprocess
    import threading

    from gonio.io.radiance import radiance_tool

    name = str(args[0])
    cmd = [radiance_tool(name), *map(str, args[1:])]
    err: list[str] = []
    with tempfile.TemporaryFile() as out:
        shown = {"step": 0, "t": 0.0}
        lock = threading.Lock()

        def tell() -> None:  # from the reader thread (a new bar) and the waiting loop
            with lock:
                now = time.perf_counter()
                frac = _bar_fraction("".join(err[-4:]))
                if frac is not None and frac > 0.0:
                    step = int(10 * frac)
                    if step > shown["step"] or now - shown["t"] >= 15.0:
                        left = (now - t0) * (1.0 - frac) / frac
                        progress(
                            f"{name}: {100 * frac:.0f} % ({now - t0:.0f} s, "
                            f"about {left:.0f} s left)"
                        )
                        shown.update(step=step, t=now)
                elif now - shown["t"] >= 15.0:
                    progress(f"{name}: {now - t0:.0f} s (about {estimate:.0f} s when idle)")
                    shown["t"] = now

        def read() -> None:
            assert proc.stderr is not None
            while chunk := proc.stderr.read1(4096):  # type: ignore[attr-defined]
                err.append(chunk.decode(errors="replace"))
                if progress is not None:
                    tell()

        reader = threading.Thread(target=read, daemon=True)
        proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.PIPE, cwd=cwd)
        # from here on a signal (Ctrl-C, SIGTERM) ends the program through the finally below,
        # the reader's start included (Thread.start waits for the thread: an interrupt there
        # left the program running on, unkilled)
        try:
            t0 = time.perf_counter()
            shown["t"] = t0
            reader.start()
            while True:
                try:
                    left = timeout - (time.perf_counter() - t0)
                    rc = proc.wait(timeout=min(15.0, max(left, 0.01)))
                    break
                except subprocess.TimeoutExpired:
                    if time.perf_counter() - t0 >= timeout:
                        raise
                    if progress is not None:
                        tell()
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            if reader.ident is not None:  # (started)
                reader.join()
            proc.stderr.close()  # type: ignore[union-attr]
        if rc != 0:
            text = "".join(err)
            lines = text.replace("\r", "\n").splitlines()
            msg = "\n".join(x for x in lines if x.strip() and not _is_bar(x))
            raise RuntimeError(f"{name} failed (exit {rc}): {msg.strip()}")
        out.seek(0)
        return out.read()


def _timed(
    seconds: dict[str, float],
    args: list,
    cwd: Any,
    timeout: float,
    progress: Progress | None = None,
    estimate: float = 0.0,
) -> bytes:
    """:func:`_run_reporting`, recording its wall time as ``seconds[name]`` and its
    processor time (user + system of the finished child) as ``seconds[name + "_cpu"]``:
    the work, independent of how busy the machine is."""
    import resource

    def cpu() -> float:
        r = resource.getrusage(resource.RUSAGE_CHILDREN)
        return r.ru_utime + r.ru_stime

    c0, t0 = cpu(), time.perf_counter()
    out = _run_reporting(args, cwd, timeout, progress, estimate)
    seconds[str(args[0])] = time.perf_counter() - t0
    seconds[f"{args[0]}_cpu"] = cpu() - c0
    if progress is not None:
        progress(f"{args[0]}: done in {seconds[str(args[0])]:.1f} s")
    return out


def _finish(
    xml: bytes,
    tmp: str,
    folder: Path,
    name: str,
    kind: str,
    sym: str,
    up: list[float],
    seconds: dict[str, float],
    timeout: float,
    note: str,
) -> BSDFBuild:
    """checkBSDF the XML, then write it and its ``void BSDF`` primitive atomically."""
    Path(tmp, "out.xml").write_bytes(xml)
    check = _timed(seconds, ["checkBSDF", "out.xml"], tmp, timeout).decode()
    xml_path = atomic_write_bytes(folder / f"{name}.xml", xml)
    rad = (
        f"# {note}\n# up = the sample's y axis; the BSDF's front is the side the normal faces\n"
        f"void BSDF {name}\n6 0 {xml_path.name} {up[0]:.9g} {up[1]:.9g} {up[2]:.9g} .\n0\n0\n"
    )
    rad_path = atomic_write_bytes(folder / f"{name}_bsdf.rad", rad.encode())
    return BSDFBuild(xml_path, rad_path, kind, sym, seconds, check, parse_check_bsdf(check))


def build_bsdf(
    samples: BRDFSamples,
    folder: str | os.PathLike,
    sample_name: str = "gonio",
    kind: str = "klems",
    samples_per_patch: int = DEFAULT_SAMPLES_PER_PATCH,
    resolution: int = 6,
    reciprocity: bool = False,
    symmetry: str | None = None,
    up: Sequence[float] = (0.0, 1.0, 0.0),
    negative: str = "error",
    nproc: int | None = None,
    timeout: float = 3600.0,
    cells: int | None = DEFAULT_CELLS,
    spread: float | None = DEFAULT_SPREAD,
    max_lobes: int = DEFAULT_MAX_LOBES,
    progress: Progress | None = None,
) -> BSDFBuild:
    """Measured samples → PAB-Opto files → ``pabopto2bsdf`` → Klems or tensor tree XML.

    Writes ``<folder>/pabopto/*.dat`` (:func:`write_pabopto`), then, after ``checkBSDF``
    read the XML, ``<folder>/<sample_name>.xml`` and ``<folder>/<sample_name>_bsdf.rad``
    (``void BSDF <sample_name>`` with the ``up`` vector: the sample's y axis in the object's
    coordinates). The scattering interpolant stays in a temporary folder.

    Measured (``benchmarks/bench_bsdf.py``; the default campaign's rolled brass, 61
    incident directions, 173,406 samples; processor seconds, the machine shared): with the
    defaults (16 cells, spread 2: 366-710 points per direction) pabopto2bsdf 47 s and
    ``bsdf2ttree -g 5`` 147 s (``-l 2000``: 99 s, errors alike); every sample (1,323-10,070
    per direction, rotations 0°, 30°, 60°, 90°) took 31 minutes and more than 54. The tree's
    error against the fit (peak; off-peak; near grazing, signed extremes) at θi 0 / 30 /
    60 / 75° is −12 / −33.5..−46 / −32..−49 / −64..−81 % at the peak, +70..+524 % off-peak
    (beside the lobe) and −72..+402 % near grazing; the fitted model's ``.cal`` at the same
    resolution (:func:`build_model_bsdf`, 4 s) has −5 / −2..−10 / −18..−23 / −32..−48 % at
    the peak, up to +119 % off-peak and −47..+519 % near grazing: at ``-g 5`` the tree's
    cells (about 3.6° of exiting direction, and of incident direction, which moves the
    mirror direction twice as far) limit both routes; the measured route adds
    pabopto2bsdf's lobes. Uniform averaging (16 cells, no split) loses the peak
    (−54..−79 %), hence the split; 32 cells (1,026-1,363 points) took the same time
    (48 + 148 s) with the same errors, hence 16.

    The Klems route is the fast one, and its time is ``bsdf2klems``'s random sampling of
    each of the 145 × 145 patch pairs (``-n``) through the interpolant's lobes. Measured
    on the default campaign (cells 16, spread 2; processor seconds, the machine shared;
    the error of the Klems directional-hemispherical reflectance of each incident patch
    against the fit's albedo, θi ≤ 70°, which checkBSDF's numbers follow): pabopto2bsdf
    27-37 s (``-n 2``: the same interpolant, the same processor time on two cores);
    bsdf2klems ``-n`` 1024 (Radiance's default): 160 s, rms 3.7 %, largest 10.7 %; 256:
    39 s, 3.9 %, 10.6 %; 128: 22 s, 3.9 %, 16 %; 64: 13.5 s, 4.2 %, 13 %; 16: 4 s, 5.5 %,
    18 % (checkBSDF: Lambertian 0.091 and largest directional reflectance 0.410-0.414 for
    all). Hence 128 (:data:`DEFAULT_SAMPLES_PER_PATCH`): the interpolation's error, not
    the sampling's, dominates from there. ``bsdf2klems -l`` (fewer lobes) is no way out:
    ``-l 1000`` halved the time and lost 28 % (rms) of the reflectance. Cells 8 (25,452
    points against 35,564) did not make pabopto2bsdf faster (37 s).

    The whole command at the defaults on an idle 2-core machine (``gonio export bsdf
    --negative clip`` of the default campaign's ``samples.csv``, ``/usr/bin/time``): 57.0 s
    of wall time, 86.9 s of processor time, 72 MB peak; pabopto2bsdf 31.0 s (60.7 processor
    seconds on its two processes: the estimate it prints, :data:`_SECONDS_PER_DIRECTION`,
    is taken from this run), bsdf2klems 24.5 s, checkBSDF and the files the rest.

    Parameters
    ----------
    kind : {"klems", "ttree"}
        ``bsdf2klems`` (145 × 145 patch matrix) or ``bsdf2ttree`` (tensor tree; slow for a
        campaign's table: minutes).
    samples_per_patch : int
        ``bsdf2klems -n`` (:data:`DEFAULT_SAMPLES_PER_PATCH`; Radiance's 1024 takes eight
        times as long for the same error, see above).
    resolution : int
        ``bsdf2ttree -g``, log2 of the tree's peak resolution, 4..7.
    reciprocity : bool
        ``bsdf2ttree +a``: reciprocity averaging (reduces measurement noise).
    symmetry : {"isotropic", "quadrilateral", "bilateral", "up", "anisotropic"}, optional
        ``pabopto2bsdf -s``; default its inference, checked beforehand
        (:func:`pabopto_symmetry`).
    nproc : int, optional
        ``pabopto2bsdf -n`` (processes); default the machine's processors.
    timeout : float
        Seconds each program may take before it is killed.
    cells, spread
        Averaging of the PAB-Opto files (:func:`pabopto_files`); ``cells=None``: every sample.
    max_lobes : int
        ``bsdf2ttree -l``: the most Gaussian lobes of an interpolated incident direction
        (Radiance's default 15000; 0 = no limit); bsdf2ttree's time is about proportional.
    progress : callable, optional
        Called with a line of text as each program starts (with an estimate of its time),
        goes on (bsdf2klems' and bsdf2ttree's own progress bar: per cent done and the time
        left; pabopto2bsdf: its time so far, every 15 s) and ends.
    """

    conv = _converter(kind, samples_per_patch, resolution, reciprocity)
    if nproc is None:
        nproc = min(os.cpu_count() or 1, 1024)
    _check_int("nproc", nproc, 1, 1024)
    allowed = ("isotropic", "quadrilateral", "bilateral", "up", "anisotropic")
    if symmetry is not None and symmetry not in allowed:
        raise ValueError(f"symmetry {symmetry!r}; expected one of {allowed}")
    upv = _check_up(up)
    folder = Path(folder)
    _check_int("max_lobes", max_lobes, 0, 1 << 30)
    if kind == "ttree":
        conv = [*conv, "-l", max_lobes]
    files = write_pabopto(samples, folder / "pabopto", sample_name, negative, cells, spread)
    sym = pabopto_symmetry([(t, p) for t, p, _ in incidences(samples)])
    seconds: dict[str, float] = {}
    est = _SECONDS_PER_DIRECTION * len(files)
    wall = est / min(nproc, os.cpu_count() or 1)
    if progress is not None:
        progress(
            f"pabopto2bsdf: {len(files)} incident directions on {nproc} process(es) "
            f"(about {wall:.0f} s on an idle machine)"
        )
    with tempfile.TemporaryDirectory(prefix="gonio_bsdf_", dir=folder) as tmp:
        args = ["pabopto2bsdf", "-n", nproc] + (["-s", symmetry] if symmetry else [])
        sir = _timed(
            seconds, [*args, *(f.name for f in files)], files[0].parent, timeout, progress, wall
        )
        Path(tmp, "refl.sir").write_bytes(sir)
        if progress is not None:
            est = (
                f"about {_KLEMS_SECONDS_PER_SAMPLE * samples_per_patch:.0f} s for the default "
                "campaign's table"
                if kind == "klems"
                else "minutes"
            )
            progress(f"{conv[0]}: {' '.join(map(str, conv[1:]))} ({est})")
        xml = _timed(seconds, [*conv, "refl.sir"], tmp, timeout, progress)
        note = f"{SYMMETRIES[sym]} {kind} BSDF of {sample_name} from {len(files)} PAB-Opto files"
        return _finish(xml, tmp, folder, sample_name, kind, sym, upv, seconds, timeout, note)


def build_model_bsdf(
    model: Any,
    folder: str | os.PathLike,
    name: str = "gonio",
    kind: str = "klems",
    samples_per_patch: int = 1024,
    resolution: int = 6,
    up: Sequence[float] = (0.0, 1.0, 0.0),
    timeout: float = 3600.0,
) -> BSDFBuild:
    """A fitted model's BSDF XML: its exact ``.cal`` (:func:`gonio.io.radiance.cal_function`)
    through ``bsdf2klems -f`` or ``bsdf2ttree -t3/-t4 -f``, then ``checkBSDF``.

    Writes ``<folder>/<name>.xml``, ``<folder>/<name>_bsdf.rad`` and the ``.cal`` it was
    built from (``<folder>/<name>_bsdf.cal``). ``-t3`` (isotropic tree) when the model is
    isotropic about the normal (α_x = α_y for the Ward family, Lambert, Cook-Torrance,
    Lafortune with C_x = C_y), ``-t4`` otherwise. Other parameters as :func:`build_bsdf`.
    """
    from gonio.brdf.composite import Sum
    from gonio.io.radiance import _identifier, cal_function

    conv = _converter(kind, samples_per_patch, resolution, False)
    if not isinstance(name, str) or not _NAME.match(name):
        raise ValueError(f"name {name!r} must be a word (letters, digits, _ . -)")
    upv = _check_up(up)
    prefix = "m" + _identifier(name)
    _, cal = cal_function(model, prefix)
    comps = model.models if isinstance(model, Sum) else [model]
    iso = all(_isotropic(c) for c in comps)
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"folder {str(folder)!r} is not an existing directory")
    cal_path = atomic_write_bytes(folder / f"{name}_bsdf.cal", cal.encode())
    if kind == "ttree":
        conv = [conv[0], "-t3" if iso else "-t4", *conv[1:]]
    seconds: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="gonio_bsdf_", dir=folder) as tmp:
        xml = _timed(seconds, [*conv, "-f", cal_path.name, f"{prefix}_bsdf"], folder, timeout)
        sym = "I" if iso else "A"
        note = f"{kind} BSDF of the fitted {model!r}"
        return _finish(xml, tmp, folder, name, kind, sym, upv, seconds, timeout, note)


def _isotropic(m: Any) -> bool:
    p = m.params
    if "alpha_x" in p:
        return p["alpha_x"] == p["alpha_y"]
    if "lobes" in p:
        return all(float(lobe[0]) == float(lobe[1]) for lobe in p["lobes"])
    return True


def _unit(theta_deg: np.ndarray, phi_deg: np.ndarray) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def bsdf_values(
    xml_path: str | os.PathLike, wi_deg: tuple[float, float], wo_deg: np.ndarray
) -> np.ndarray:
    """Front reflection of a BSDF XML (Radiance's ``SDevalBSDF`` through pyradiance).

    ``wi_deg`` is ``(θi, φi)`` and ``wo_deg`` an ``(N, 2)`` array of ``(θo, φo)`` in degrees,
    in the sample frame (the XML's standard axes; :func:`pabopto_files` writes ``#upphi
    90`` so that they are gonio's). Returns the photometric (CIE Y) values in sr⁻¹, shape
    ``(N,)``.
    """
    import pyradiance.bsdf as rb

    sd = _LOADED.get(str(xml_path))
    if sd is None:  # pyradiance owns the loaded data (an explicit free double-frees)
        sd = _LOADED[str(xml_path)] = rb.load_file(str(xml_path))
    ti, pi = (float(x) for x in wi_deg)
    return np.array([float(rb.query(sd, ti, pi, float(t), float(p))[1]) for t, p in wo_deg])


_LOADED: dict[str, Any] = {}


#: the exiting directions of :func:`bsdf_error_table` (θo; φo every 30°): off-peak (those
#: outside the lobe) and near grazing
OFF_PEAK_THETA_DEG = (10.0, 25.0, 40.0, 55.0, 70.0)
GRAZING_THETA_DEG = (80.0, 85.0)


def bsdf_error_table(
    xml_path: str | os.PathLike,
    references: dict[str, Any],
    theta_i_deg: Sequence[float] = (0.0, 30.0, 60.0, 75.0),
    phi_i_deg: Sequence[float] = (0.0, 45.0, 90.0),
) -> list[dict[str, Any]]:
    """A BSDF XML's front reflection against reference BRDFs: peak, off-peak, near grazing.

    For each incidence ``(θi, φi)`` (normal incidence once): ``peak`` the XML's value at
    the mirror direction; ``off_peak`` the exiting directions θo in
    :data:`OFF_PEAK_THETA_DEG`, φo every 30°, where the first reference is below twice its
    smallest value over them (outside the lobe, on the diffuse floor); ``grazing`` θo in
    :data:`GRAZING_THETA_DEG`, φo every 30°. Each row holds, per reference (e.g.
    ``{"fit": model, "truth": model}``), the relative error ``xml / reference − 1`` at the
    peak and the signed error of largest magnitude off-peak and near grazing
    (``<ref>_peak``, ``<ref>_off_peak``, ``<ref>_grazing``).
    """
    phis = np.arange(0.0, 360.0, 30.0)
    first = next(iter(references.values()))
    rows = []
    for ti in theta_i_deg:
        for pi in phi_i_deg if ti > 0 else phi_i_deg[:1]:
            wi = _unit(np.array(ti), np.array(pi))
            mirror = np.array([[ti, (pi + 180.0) % 360.0]])
            t, p = np.meshgrid(OFF_PEAK_THETA_DEG, phis, indexing="ij")
            off = np.stack([t.ravel(), p.ravel()], axis=1)
            floor = np.asarray(first(wi, _unit(off[:, 0], off[:, 1])), dtype=float)
            off = off[floor < 2.0 * floor.min()]
            t, p = np.meshgrid(GRAZING_THETA_DEG, phis, indexing="ij")
            graz = np.stack([t.ravel(), p.ravel()], axis=1)
            row: dict[str, Any] = {"theta_i": float(ti), "phi_i": float(pi)}
            for part, wo in (("peak", mirror), ("off_peak", off), ("grazing", graz)):
                got = bsdf_values(xml_path, (ti, pi), wo)
                if part == "peak":
                    row["peak"] = float(got[0])
                for name, model in references.items():
                    want = np.asarray(model(wi, _unit(wo[:, 0], wo[:, 1])), dtype=float)
                    err = got / want - 1.0
                    row[f"{name}_{part}"] = float(err[np.argmax(np.abs(err))])
            rows.append(row)
    return rows
