"""Image metrics and the bias/variance split, on images whose answers are known."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import ImageOutput, run_evalkit

from evalkit.core.errors import InputError
from evalkit.core.exr import read_exr, write_exr
from evalkit.metrics.images import bias_variance, compare_images, delta_e2000, flip, mse, relmse, smape


def test_a_constant_offset_gives_the_closed_form_values():
    ref = np.full((16, 24, 3), 1.0)
    test = ref + 0.1
    assert mse(test, ref).value == pytest.approx(0.01, rel=1e-12)
    assert relmse(test, ref).value == pytest.approx(0.01 / 1.01, rel=1e-12)
    assert relmse(test, ref, eps=0.5).value == pytest.approx(0.01 / 1.5, rel=1e-12)
    assert smape(test, ref).value == pytest.approx(0.1 / 2.11, rel=1e-12)
    assert relmse(test, ref).params == {"epsilon": 0.01}


def test_error_maps_locate_a_known_error():
    ref = np.full((20, 30, 3), 0.5)
    test = ref.copy()
    test[7, 11] = [0.5, 0.8, 0.2]  # channel errors 0, 0.3, -0.3
    m = mse(test, ref)
    assert m.map.shape == (20, 30)
    assert m.map[7, 11] == pytest.approx((0.09 + 0.09) / 3)
    assert np.count_nonzero(m.map) == 1
    assert m.value == pytest.approx(m.map[7, 11] / 600)
    f = flip(test, ref)
    assert f.map.shape == (20, 30)
    assert np.unravel_index(np.argmax(f.map), f.map.shape) == (7, 11) and f.map[7, 11] > 0.05
    yy, xx = np.mgrid[:20, :30]
    distance = np.hypot(yy - 7, xx - 11)
    # FLIP's filters (67 pixels per degree) spread the error: measured 7 % of the peak beyond 6
    # pixels, 0.5 % beyond 10 and nothing beyond 15.
    assert f.map[distance > 10].max() < 0.01 * f.map[7, 11]
    assert f.map[distance > 15].max() == 0.0


def test_flip_and_delta_e_are_zero_for_identical_images_and_grow_with_the_error(rng):
    ref = rng.random((32, 32, 3)) * 2.0
    assert flip(ref, ref).value == 0.0
    assert delta_e2000(ref, ref).value == 0.0
    small, large = flip(ref * 1.05, ref).value, flip(ref * 1.5, ref).value
    assert 0 < small < large
    assert flip(ref * 1.5, ref).params["dynamic_range"] == "HDR"


def test_flip_of_a_black_reference_is_undefined_not_the_end_of_the_process(tmp_path):
    # flip-evaluator picks its exposure range from the reference and ends the process when the range
    # is empty (a black reference: the indirect image of a scene without indirect light).
    black, lit = np.zeros((8, 8, 3)), np.ones((8, 8, 3))
    for reference in (black, np.full((8, 8, 3), 1e-12)):
        m = flip(lit, reference)
        assert np.isnan(m.value) and m.params["undefined"].startswith("the reference is black")
    assert flip(black, lit).value > 0.5  # a black test image against a lit reference is measured
    write_exr(tmp_path / "lit.exr", lit.astype(np.float32), {"what": "test"})
    write_exr(tmp_path / "black.exr", black.astype(np.float32), {"what": "reference"})
    r = run_evalkit("compare", str(tmp_path / "lit.exr"), str(tmp_path / "black.exr"))
    assert r.returncode == 0 and "undefined the reference is black" in r.stdout


def test_view_says_where_an_image_is_nan_and_shows_it_black(tmp_path):
    image = np.ones((4, 6, 3), np.float32)
    image[2, 5, 1] = np.nan
    write_exr(tmp_path / "hole.exr", image, {"what": "test"})
    r = run_evalkit("view", str(tmp_path / "hole.exr"), "--png", str(tmp_path / "hole.png"))
    assert r.returncode == 0 and "1 pixel(s) are NaN or Inf, the first at x=5, y=2 (NaN shown black)" in r.stdout
    assert "RuntimeWarning" not in r.stderr
    from PIL import Image

    png = np.asarray(Image.open(tmp_path / "hole.png"))
    assert tuple(png[2, 5]) == (255, 0, 255) and tuple(png[0, 0]) == (255, 255, 255)


def test_delta_e2000_matches_sharmas_published_pair():
    # Sharma, Wu and Dalal (2005), pair 7: Lab (50, 0, 0) and (50, -1, 2) differ by 2.3669.
    import colour

    d65 = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D65"]

    def linear_rgb(lab):
        xyz = colour.Lab_to_XYZ(np.array(lab, dtype=np.float64), d65)
        return colour.XYZ_to_RGB(xyz, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_encoding=False)

    a, b = linear_rgb([50.0, 0.0, 0.0]), linear_rgb([50.0, -1.0, 2.0])
    assert np.all((a > 0) & (a < 1)) and np.all((b > 0) & (b < 1))
    m = delta_e2000(np.full((4, 4, 3), b), np.full((4, 4, 3), a))
    assert m.value == pytest.approx(2.3669, abs=5e-4)
    # One stop of exposure is applied before the display: the same pair, half as bright, matches.
    assert delta_e2000(np.full((4, 4, 3), b / 2), np.full((4, 4, 3), a / 2), exposure=1.0).value == pytest.approx(
        2.3669, abs=5e-4
    )


def test_bad_images_are_refused_with_the_image_named():
    ref = np.zeros((8, 8, 3))
    bad = ref.copy()
    bad[3, 5, 1] = np.nan
    with pytest.raises(InputError, match=r"render.exr: 1 pixel\(s\) are NaN or Inf, the first at x=5, y=3"):
        compare_images(bad, ref, test_name="render.exr")
    bad[3, 5, 1] = np.inf
    with pytest.raises(InputError, match="ref.exr"):
        compare_images(ref, bad, ref_name="ref.exr")
    with pytest.raises(InputError, match="is 4x8 but reference is 8x8"):
        compare_images(np.zeros((8, 4, 3)), ref)
    with pytest.raises(InputError, match="unknown metric"):
        compare_images(ref, ref, metrics=["psnr"])


def test_bias_and_variance_are_split_on_known_noise(rng):
    ref = np.full((64, 64, 3), 1.0)
    bias, sigma, n = 0.05, 0.2, 8
    images = [ref + bias + rng.normal(0, sigma, ref.shape) for _ in range(n)]
    bv = bias_variance(images, ref)
    w = 1 / 1.01
    assert bv["variance"] == pytest.approx(sigma**2 * w, rel=0.03)
    assert bv["bias2"] == pytest.approx(bias**2 * w, rel=0.1)
    assert bv["relmse_mean"] == pytest.approx((bias**2 + sigma**2) * w, rel=0.03)
    assert bv["relmse_min"] <= bv["relmse_mean"] <= bv["relmse_max"] and bv["relmse_std"] > 0
    unbiased = bias_variance([ref + rng.normal(0, sigma, ref.shape) for _ in range(n)], ref)
    assert abs(unbiased["bias2"]) < 0.05 * unbiased["variance"]
    with pytest.raises(ValueError, match="at least 2 seeds"):
        bias_variance(images[:1], ref)


def test_compare_cli_prints_metrics_and_writes_error_maps(tmp_path):
    ref = np.full((16, 16, 3), 0.25, np.float32)
    write_exr(tmp_path / "ref.exr", ref, {"what": "reference"})
    write_exr(tmp_path / "test.exr", ref + 0.05, {"what": "test"})
    r = run_evalkit(
        "compare", str(tmp_path / "test.exr"), str(tmp_path / "ref.exr"), "--maps", str(tmp_path / "maps"), "--json"
    )
    assert r.returncode == 0, r.stderr
    import json

    values = json.loads(r.stdout.splitlines()[-1])
    assert values["mse"]["value"] == pytest.approx(0.0025, rel=1e-5)
    assert values["relmse"]["params"] == {"epsilon": 0.01}
    for name in ("mse", "relmse", "smape", "flip", "delta_e2000"):
        assert (tmp_path / "maps" / f"{name}.exr").is_file() and (tmp_path / "maps" / f"{name}.png").is_file()
    bad = ref.copy()
    bad[0, 0, 0] = np.inf
    write_exr(tmp_path / "bad.exr", bad, {})
    r = run_evalkit("compare", str(tmp_path / "bad.exr"), str(tmp_path / "ref.exr"))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"evalkit: error: {tmp_path / 'bad.exr'}: 1 pixel(s) are NaN or Inf, the first at x=0, y=0"
    ]


def test_a_failing_image_comparison_keeps_its_images_where_the_message_says(tmp_path):
    ref = np.full((8, 12, 3), 0.5, dtype=np.float32)
    test = ref.copy()
    test[3, 4] = 2.0
    out = ImageOutput("tests/test_x.py::test_y[a]", root=tmp_path)
    assert out.relmse_at_most("indirect", ref, ref, 0.0) == 0.0  # passing: nothing is written
    assert not any(tmp_path.iterdir())
    with pytest.raises(AssertionError) as failure:
        out.relmse_at_most("indirect", test, ref, 1e-3)
    folder = tmp_path / "tests_test_x.py_test_y_a_" / "indirect"
    assert str(folder) in str(failure.value) and "relMSE" in str(failure.value)
    kept = {p.name for p in folder.iterdir()}
    assert kept == {"test.exr", "reference.exr", "relmse_map.exr", "relmse_map.png"}
    image, provenance = read_exr(folder / "test.exr")
    assert np.array_equal(image, test) and provenance["image"] == "indirect"
