"""Mitsuba 3 path-traced references: direct, indirect (exactly B bounces) and total images, each
with a per-pixel variance image, in a store keyed by the scene's content hash.

How the images are made:

- The scene is rendered through its Mitsuba export (`to_mitsuba_dict`: same camera, box pixel
  filter, float32 film) with Mitsuba's own ``path`` integrator, Russian roulette off
  (``rr_depth = max_depth``).
- **direct** is ``max_depth = 2`` (emitters seen directly plus direct lighting), **total** is
  ``max_depth = B + 2``, and **indirect = total - direct**, from two renders that share a seed.
  Both renders draw the same random numbers for the first vertex, so every sample's direct part
  cancels exactly and the difference is the B-bounce indirect estimate of the same paths. This
  was chosen over a registered Python integrator because the reference is then Mitsuba's own
  C++ integrator, untouched, so it cannot carry an integrator bug of ours.
- **Variance.** The ``moment`` integrator records its moments in XYZ for RGB variants (checked with
  3.9.1), and it cannot give the variance of a difference of two renders. So the spp are rendered
  in C chunks with independent seeds, and the variance image is the variance of the pixel mean
  from the spread of the chunk means (batch means, C - 1 degrees of freedom), per RGB channel,
  for all three images alike.
- Chunks also make long renders resumable: after each chunk the running sums go to
  ``progress.npz`` in the entry's folder, and a rerun with the same parameters continues there.

Store layout: ``STORE/<scene>-<hash16>/b<B>_<W>x<H>_spp<S>_seed<N>/`` with ``direct.exr``,
``indirect.exr``, ``total.exr``, ``<image>_variance.exr`` and ``manifest.json``. The key holds every
parameter that changes the images; the Mitsuba variant is recorded but not keyed (the same seed
gives the same image on llvm and scalar).

One writer per entry: rendering holds the entry folder's lock (`evalkit.core.lock`), so two
processes that need the same reference (two studies sharing a store, a study's workers) never
render it twice; the second refuses in one line, or with ``wait`` waits and then reuses it.
Entries are locked one by one, so different references of one store render side by side.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evalkit.core import VERSION
from evalkit.core.atomic import atomic_path, write_text
from evalkit.core.cache import CACHE_VARIABLE, cache_root
from evalkit.core.errors import InputError
from evalkit.core.exr import read_exr, write_exr
from evalkit.core.lock import folder_lock
from evalkit.core.mitsuba_env import mitsuba
from evalkit.core.scene import Scene
from evalkit.core.scene.mitsuba_io import to_mitsuba_dict
from evalkit.core.settings import IMAGES

# The small references CI uses, committed (make references). Read first; written only when named.
COMMITTED_STORE = Path(__file__).resolve().parent / "store"
STORE_VARIABLE = "EVALKIT_REFERENCE_STORE"
STORE_FORMAT = 1
DEFAULT_CHUNKS = 32
TIMED_STREAM = 2**31  # the chunk index of `timed_render`'s samples: references use 0 .. chunks - 1


@dataclass
class Reference:
    """A stored reference: images and variances (H, W, 3) float32 by name, and its manifest."""

    path: Path
    images: dict[str, np.ndarray]
    variances: dict[str, np.ndarray]
    manifest: dict
    reused: bool


def store_entry(
    scene_name: str,
    scene_hash: str,
    bounces: int,
    spp: int,
    width: int,
    height: int,
    seed: int,
    store: Path,
) -> Path:
    """The store folder of one reference."""
    return Path(store) / f"{scene_name}-{scene_hash[:16]}" / f"b{bounces}_{width}x{height}_spp{spp}_seed{seed}"


def user_store() -> Path:
    """Where references of your own scenes go, never the checkout: ``$EVALKIT_REFERENCE_STORE``,
    else the user cache's ``references/`` (`evalkit.core.cache`: ``$EVALKIT_CACHE``, else
    ``$XDG_CACHE_HOME/evalkit``, else ``~/.cache/evalkit``)."""
    if os.environ.get(STORE_VARIABLE):
        return Path(os.environ[STORE_VARIABLE])
    root = cache_root()
    if root is None:
        raise InputError(STORE_VARIABLE, f"{CACHE_VARIABLE}=off leaves references no store; give --store or set it")
    return root / "references"


def chunk_seed(seed: int, chunk: int) -> int:
    """An independent 32-bit Mitsuba seed per chunk."""
    return int(np.random.SeedSequence([seed, chunk]).generate_state(1)[0])


def reference(
    scene: Scene,
    bounces: int = 1,
    spp: int = 1024,
    width: int | None = None,
    height: int | None = None,
    seed: int = 0,
    chunks: int | None = None,
    variant: str | None = None,
    store: Path | None = None,
    progress=print,
    wait: bool = False,
) -> Reference:
    """The stored reference with these parameters, rendered (or resumed) first if it is missing.

    ``chunks`` (default ``min(32, spp)``) must divide ``spp``; ``progress`` gets one line per chunk
    (None: quiet).
    Another process rendering the same entry is an `InputError`, or with ``wait`` is waited for.
    ``store`` None: the committed CI store when it has the entry, else `user_store`.
    """
    width, height = scene.camera.film_size(width, height)
    if bounces < 0 or spp < 2 or width < 1 or height < 1:
        raise ValueError(f"need bounces >= 0, spp >= 2 and a positive size, got {bounces}, {spp}, {width}x{height}")
    chunks = int(chunks or min(DEFAULT_CHUNKS, spp))
    if chunks < 2 or spp % chunks:
        raise ValueError(
            f"{chunks} chunks must be at least 2 and divide spp={spp} (the variance comes from the chunks)"
        )
    scene_hash = scene.content_hash()
    progress = progress or (lambda line: None)
    if store is None:
        committed = store_entry(scene.name, scene_hash, bounces, spp, width, height, seed, COMMITTED_STORE)
        store = COMMITTED_STORE if (committed / "manifest.json").is_file() else user_store()
    entry = store_entry(scene.name, scene_hash, bounces, spp, width, height, seed, store)
    if (entry / "manifest.json").is_file():
        return load_reference(entry, reused=True)
    with folder_lock(entry, "reference render", wait=wait, progress=progress):
        if (entry / "manifest.json").is_file():  # finished by the process this one waited for
            return load_reference(entry, reused=True)
        return _render_entry(scene, scene_hash, entry, bounces, spp, width, height, seed, chunks, variant, progress)


def _render_entry(scene, scene_hash, entry, bounces, spp, width, height, seed, chunks, variant, progress) -> Reference:
    mi, mi_scene, integrators = _mitsuba_scene(scene, bounces, spp // chunks, width, height, variant)
    state_path = entry / "progress.npz"
    done, sums, squares = 0, np.zeros((3, height, width, 3)), np.zeros((3, height, width, 3))
    if state_path.is_file():
        with np.load(state_path) as z:
            if int(z["chunks"]) == chunks:  # chunk seeds and sizes follow the chunk count
                done, sums, squares = int(z["done"]), z["sums"], z["squares"]
                progress(f"resuming {entry} at chunk {done + 1} of {chunks}")
            else:
                progress(f"starting {entry} again: the saved progress is for {int(z['chunks'])} chunks, not {chunks}")
    start, resumed_at = time.perf_counter(), done
    for chunk in range(done, chunks):
        means = chunk_images(mi, mi_scene, integrators, bounces, chunk_seed(seed, chunk))
        sums += means
        squares += means * means
        done = chunk + 1
        with atomic_path(state_path) as tmp:
            np.savez(tmp, done=done, chunks=chunks, sums=sums, squares=squares)
        elapsed = time.perf_counter() - start
        per_chunk = elapsed / (done - resumed_at)
        progress(
            f"chunk {done}/{chunks}: {spp // chunks} spp, {elapsed:.1f} s, "
            f"about {per_chunk * (chunks - done):.0f} s left"
        )

    mean = sums / chunks
    variance = np.maximum(squares - chunks * mean * mean, 0.0) / (chunks * (chunks - 1))
    manifest = {
        "store_format": STORE_FORMAT,
        "scene": scene.name,
        "scene_source": scene.source,
        "scene_hash": scene_hash,
        "bounces": bounces,
        "spp": spp,
        "seed": seed,
        "chunks": chunks,
        "width": width,
        "height": height,
        "integrator": f"path, max_depth 2 (direct) and {bounces + 2} (total), rr_depth = max_depth; "
        "indirect = total - direct",
        "variance": "variance of the pixel mean from the spread of the chunk means (batch means), per RGB channel",
        "mitsuba": mi.__version__,
        "variant": mi.variant(),
        "evalkit": VERSION,
        "warnings": list(scene.warnings),
        "render_s": round(time.perf_counter() - start, 3),
        "files": {},
    }
    for i, name in enumerate(IMAGES):
        for suffix, image in (("", mean[i]), ("_variance", variance[i])):
            file = f"{name}{suffix}.exr"
            write_exr(
                entry / file, image, {**{k: v for k, v in manifest.items() if k != "files"}, "image": name + suffix}
            )
            manifest["files"][name + suffix] = file
    # Last and whole: an entry is finished only with its manifest (a crash before leaves none).
    write_text(entry / "manifest.json", json.dumps(manifest, indent=2) + "\n")
    state_path.unlink()
    return load_reference(entry, reused=False)


def _mitsuba_scene(scene: Scene, bounces: int, spp: int, width: int, height: int, variant: str | None):
    """Mitsuba, the scene loaded at ``spp`` per render, and the path integrators for the direct
    image (max_depth 2) and the total one (max_depth bounces + 2), by max_depth."""

    mi = mitsuba(variant)
    mi_scene = mi.load_dict(to_mitsuba_dict(scene, mi, spp=spp, width=width, height=height))
    return mi, mi_scene, path_integrators(mi, bounces)


def path_integrators(mi, bounces: int) -> dict:
    """Mitsuba's path integrators for the direct image (max_depth 2) and the total one (max_depth
    bounces + 2), by max_depth, Russian roulette off."""
    return {depth: mi.load_dict({"type": "path", "max_depth": depth, "rr_depth": depth}) for depth in (2, bounces + 2)}


def chunk_images(mi, mi_scene, integrators: dict, bounces: int, seed: int, sensor=None) -> np.ndarray:
    """One chunk's direct, indirect and total images (3, H, W, 3) float64: the direct and total
    renders share ``seed``, so the indirect image is their difference (module docstring). ``sensor``:
    another sensor than the scene's own."""
    kw = {} if sensor is None else {"sensor": sensor}
    direct = np.array(mi.render(mi_scene, integrator=integrators[2], seed=seed, **kw), dtype=np.float64)[..., :3]
    total = np.array(mi.render(mi_scene, integrator=integrators[bounces + 2], seed=seed, **kw), dtype=np.float64)
    return np.stack([direct, total[..., :3] - direct, total[..., :3]])


def timed_render(
    scene: Scene, bounces: int, spp: int, width: int, height: int, seed: int, variant: str | None = None
) -> tuple[dict[str, np.ndarray], float, dict]:
    """Mitsuba's direct, indirect and total images at ``spp`` and the seconds they took, for
    comparing speed against error: a 1-spp warm-up render first compiles Mitsuba's kernels, so the
    time is rendering only. Both the direct and the total render are timed, as the indirect image
    needs both. ``seed`` goes through `chunk_seed` with a chunk index no reference uses, so a test
    image never shares samples with a stored reference of the same seed. Returns images, seconds
    and provenance."""
    mi, mi_scene, integrators = _mitsuba_scene(scene, bounces, spp, width, height, variant)
    for integrator in integrators.values():
        mi.render(mi_scene, integrator=integrator, seed=1, spp=1)
    seed = chunk_seed(seed, TIMED_STREAM)
    # spp given again: a render's spp argument stays set on the scene's sampler.
    start = time.perf_counter()
    direct = np.array(mi.render(mi_scene, integrator=integrators[2], seed=seed, spp=spp), dtype=np.float64)[..., :3]
    total = np.array(mi.render(mi_scene, integrator=integrators[bounces + 2], seed=seed, spp=spp), dtype=np.float64)[
        ..., :3
    ]
    seconds = time.perf_counter() - start
    images = {"direct": direct, "indirect": total - direct, "total": total}
    return images, seconds, {"mitsuba": mi.__version__, "variant": mi.variant()}


def load_reference(entry: str | os.PathLike, reused: bool = True) -> Reference:
    """A stored reference folder (or one copied out of the store)."""
    entry = Path(entry)
    manifest_path = entry / "manifest.json"
    if not manifest_path.is_file():
        raise InputError(str(entry), "no manifest.json: not a reference folder")
    try:
        manifest = json.loads(manifest_path.read_text())
    except ValueError as e:
        raise InputError(str(manifest_path), f"malformed JSON: {e}") from None
    if manifest.get("store_format") != STORE_FORMAT:
        raise InputError(
            str(manifest_path), f"reference store format {manifest.get('store_format')} is not {STORE_FORMAT}"
        )
    images = {name: read_exr(entry / manifest["files"][name])[0] for name in IMAGES}
    variances = {name: read_exr(entry / manifest["files"][name + "_variance"])[0] for name in IMAGES}
    return Reference(entry, images, variances, manifest, reused)


def export_reference(ref: Reference, out: str | os.PathLike) -> list[Path]:
    """Copy a reference's files and manifest into ``out``; returns the written paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for file in [*ref.manifest["files"].values(), "manifest.json"]:
        written.append(Path(shutil.copy2(ref.path / file, out / file)))
    return written
