"""How sure a comparison is (evalkit/metrics/confidence.py): the mean ratio's interval covers the
truth as often as it says (against a reference, and between two renders, paired frame by frame
or not), the z-test finds a bias the noise cannot explain and nothing where there is none, and a
render's own account of its noise (per-pixel variance of the mean, the frames' image means) is
what its frames give."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import render_with, run_evalkit

from evalkit.core.exr import read_exr, write_exr
from evalkit.metrics.confidence import mean_ratio, pool_renders, render_ratio, within, z_test
from gpu_impl.renderer import write_render


def test_the_interval_covers_the_true_ratio_as_often_as_it_says():
    rng = np.random.default_rng(3)
    truth, covered, trials = 1.02, 0, 400
    ref_var = np.full((8, 8, 3), 1e-4)  # the reference's pixels: independent, known variance
    for _ in range(trials):
        frames = truth * 0.5 + rng.normal(0, 0.05, (16, 3))  # 16 frames' image means, true mean 0.51
        ref = 0.5 + rng.normal(0, 1e-2, (8, 8, 3))  # its noise: what ref_var says
        r = mean_ratio(frames, ref, ref_var)["all"]
        covered += r["lo"] <= truth <= r["hi"]
    assert 0.92 <= covered / trials <= 0.98


def test_the_ratio_of_two_renders_covers_the_truth_as_often_as_it_says_paired_or_not():
    # Two methods' frames share most of their noise when they share their seed (the frame's
    # directions): pairing cancels it, and the interval stays honest with or without it.
    rng = np.random.default_rng(4)
    truth, trials = 0.97, 400
    covered = {"paired": 0, "unpaired": 0}
    width = {"paired": [], "unpaired": []}
    for _ in range(trials):
        shared = rng.normal(0, 0.1, (20, 3))
        base = 0.5 * (1 + shared + rng.normal(0, 0.005, (20, 3)))
        test = truth * 0.5 * (1 + shared + rng.normal(0, 0.005, (20, 3)))
        other = 0.5 * (1 + rng.normal(0, 0.1, (12, 3)))  # another seed, another frame count
        for key, r in (("paired", render_ratio(test, base)), ("unpaired", render_ratio(test, other))):
            assert r["paired"] == (key == "paired")
            covered[key] += r["all"]["lo"] <= truth <= r["all"]["hi"]
            width[key].append(r["all"]["hi"] - r["all"]["lo"])
    assert all(0.92 <= c / trials <= 0.98 for c in covered.values()), covered
    assert np.median(width["paired"]) < np.median(width["unpaired"]) / 10


def test_one_frame_says_nothing_of_its_noise():
    r = mean_ratio(np.ones((1, 3)), np.ones((4, 4, 3)), np.zeros((4, 4, 3)))
    assert r["all"]["lo"] is None and not within(r["all"], 0.5)


def test_the_z_test_finds_a_bias_the_noise_cannot_explain_and_nothing_else():
    rng = np.random.default_rng(5)
    ref, var = np.full((64, 64, 3), 0.5), np.full((64, 64, 3), 1e-4)
    test = ref + rng.normal(0, np.sqrt(2e-4), ref.shape)  # both images' noise, no bias
    clean = z_test(test, var, ref, var)
    assert clean["outside"] <= 2 and clean["tested"] == 64 * 64 * 3
    biased = test.copy()
    biased[:8, :8] += 0.1  # 7 standard deviations in a corner
    found = z_test(biased, var, ref, var)
    assert found["outside_share"] == pytest.approx(8 * 8 / (64 * 64), rel=0.1)
    assert found["map"][:8, :8].min() > found["threshold"]


def test_a_render_accounts_for_its_noise_frame_by_frame(gl):
    # Frame f's pixel values are what f + 1 frames add to f frames (a render is deterministic):
    # their spread, in float64, against the renderer's running account in float32.
    kw = dict(bounces=1, directions=4, resolution=32, width=12, height=10, spp=2, seed=4)
    means = [render_with(gl, "cornell-box", frames=f, **kw) for f in (1, 2, 3, 4)]
    values = np.stack([(f + 1) * m.images["indirect"].astype(np.float64) for f, m in enumerate(means)])
    values[1:] -= np.stack([(f + 1) * m.images["indirect"].astype(np.float64) for f, m in enumerate(means[:-1])])
    last = means[-1]
    expected = values.var(axis=0, ddof=1) / len(values)
    assert np.allclose(last.variances["indirect"], expected, rtol=2e-3, atol=1e-9)
    assert np.allclose(last.frame_means["indirect"], values.mean(axis=(1, 2)), rtol=1e-4)
    assert means[0].variances is None and means[0].frame_means["direct"].shape == (1, 3)
    assert np.allclose(last.frame_means["total"], last.frame_means["direct"] + last.frame_means["indirect"])


@pytest.mark.long
def test_render_files_and_compare_carry_the_confidence(tmp_path):
    out, ref = tmp_path / "render", tmp_path / "ref"
    args = ("--bounces", "1", "--width", "16", "--height", "16")
    done = run_evalkit(
        "render", "cornell-box", "--method", "perfect", "--directions", "8", "--resolution", "32", "--frames", "4",
        *args, "--out", str(out),
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    image, meta = read_exr(out / "indirect.exr")
    assert len(meta["frame_means"]) == 4 and (out / "indirect_variance.exr").is_file()
    done = run_evalkit(
        "reference", "cornell-box", "--spp", "64", *args, "--store", str(tmp_path / "s"), "--out", str(ref)
    )
    assert done.returncode == 0, done.stderr
    done = run_evalkit("compare", str(out / "indirect.exr"), str(ref / "indirect.exr"), "--metrics", "mse", "--json")
    assert done.returncode == 0, done.stderr
    assert "mean ratio" in done.stdout and "z-test" in done.stdout
    result = json.loads(done.stdout.splitlines()[-1])
    assert result["mean_ratio"]["frames"] == 4 and result["z_test"]["tested"] > 0

    # One setting against another (R=16 over R=32): the base render's frames give its noise,
    # paired frame by frame, and a shared seed (the same directions in each frame) cancels most of
    # it. (Imperfect bundles would not do: on this box they land where perfect ones do, to round-off.)
    halves = {}
    for seed in (0, 1):
        other = tmp_path / f"coarse{seed}"
        done = run_evalkit(
            "render", "cornell-box", "--method", "perfect", "--directions", "8", "--resolution", "16",
            "--frames", "4", "--seed", str(seed), *args, "--out", str(other),
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        done = run_evalkit(
            "compare", str(other / "indirect.exr"), str(out / "indirect.exr"), "--metrics", "mse", "--json"
        )
        assert done.returncode == 0, done.stderr
        result = json.loads(done.stdout.splitlines()[-1])
        r = result["render_ratio"]
        assert r["paired"] and r["frames"] == [4, 4] and "mean_ratio" not in result
        test_means = np.asarray(read_exr(other / "indirect.exr")[1]["frame_means"])
        assert r["all"]["ratio"] == pytest.approx(test_means.mean() / np.mean(meta["frame_means"]), rel=1e-6)
        halves[seed] = (r["all"]["hi"] - r["all"]["lo"]) / 2
    assert halves[0] < halves[1] / 3, halves


def test_compare_pools_renders_of_one_setting_and_refuses_what_would_not_pool(gl, tmp_path):
    # A long check in pieces: renders of one setting under different seeds are one estimate whose
    # frames weigh the same, whatever each render's count.
    kw = dict(bounces=1, directions=4, resolution=32, width=12, height=10, spp=1)
    pieces = {"a": dict(seed=1, frames=2), "b": dict(seed=2, frames=3), "k": dict(seed=3, frames=2, directions=8)}
    for name, extra in pieces.items():
        write_render(render_with(gl, "cornell-box", **{**kw, **extra}), tmp_path / name)
    paths = [str(tmp_path / name / "indirect.exr") for name in ("a", "b")]
    read = [(p, *read_exr(p)) for p in paths]
    variances = [read_exr(p.replace(".exr", "_variance.exr"))[0] for p in paths]
    image, variance, meta = pool_renders([(p, img, v, m) for (p, img, m), v in zip(read, variances)])
    a, b = (r[1].astype(np.float64) for r in read)
    assert np.allclose(image, (2 * a + 3 * b) / 5, rtol=1e-6)
    assert np.allclose(variance, (4 * variances[0] + 9 * variances[1]) / 25, rtol=1e-6)
    assert meta["frame_means"] == read[0][2]["frame_means"] + read[1][2]["frame_means"] and meta["seed"] == [1, 2]

    # The CLI: pooled against a reference of its own size (any image with a variance beside it).
    ref = tmp_path / "ref.exr"
    write_exr(ref, np.full_like(image, 0.05), {})
    write_exr(tmp_path / "ref_variance.exr", np.full_like(image, 1e-6), {})
    done = run_evalkit("compare", *paths, str(ref), "--metrics", "mse", "--json")
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.splitlines()[-1])
    frames = np.asarray(meta["frame_means"])
    assert result["pooled"]["frames"] == 5 and result["mean_ratio"]["frames"] == 5
    assert result["mean_ratio"]["all"]["ratio"] == pytest.approx(frames.mean() / 0.05, rel=1e-5)
    assert result["mse"]["value"] == pytest.approx(float(np.mean((image - 0.05) ** 2)), rel=1e-4)

    # The same seed twice, another setting, another size, and an image that is not a render.
    write_exr(tmp_path / "small.exr", np.zeros((5, 6, 3), np.float32), {**read[0][2], "seed": 9})
    refused = {
        "images of two sizes do not pool": [paths[0], str(tmp_path / "small.exr")],
        "the same frames twice": [paths[0], paths[0]],
        "directions 8 against 4": [paths[0], str(tmp_path / "k" / "indirect.exr")],
        "has no frame means": [paths[0], str(ref)],
    }
    for problem, tests in refused.items():
        done = run_evalkit("compare", *tests, str(ref))
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and problem in done.stderr and len(lines) == 1, done.stderr
