"""RenderSettings (evalkit/core/settings.py) and the registry of units (gpu_impl/registry.py): flat
settings split into fields and the units' options, every declared setting checked by its own
declaration, a unit's setting refused (or, for defaults, left out) where the render does not use
that unit, and the command line's flags made from the declarations."""

from __future__ import annotations

from dataclasses import replace

import pytest
from conftest import run_evalkit

from evalkit.core.settings import RenderSettings, check_settings, declared
from gpu_impl.registry import KINDS, METHODS, all_units, owners, resolve


def test_flat_settings_split_into_fields_and_options_and_replace_keeps_both():
    s = RenderSettings(method="imperfect", points=4096, frames=3)
    assert s.frames == 3 and s.options == (("points", 4096),) and s.option("points") == 4096
    t = replace(s, splat_scale=2.0, bounces=2)
    assert t.options == (("points", 4096), ("splat_scale", 2.0)) and t.bounces == 2 and t.frames == 3
    assert t == RenderSettings(method="imperfect", frames=3, bounces=2, splat_scale=2.0, points=4096)
    assert hash(t) == hash(RenderSettings(**t.flat()))


def test_resolving_names_every_unit_and_fills_in_their_defaults():
    resolved = resolve(RenderSettings(method="imperfect", points=4096))
    assert {f: u.name for f, u in resolved.units.items()} == {
        field: (registry.default.name if field != "method" else "imperfect") for field, registry in KINDS.items()
    }
    params = resolved.params()
    assert params["points"] == 4096 and params["splat_scale"] == resolved.unit_settings["method"].splat_scale
    # Every setting of the chosen units is in the provenance, and none of another unit's.
    assert "light_samples" in params and "light_sample_map_size" in params
    assert "points" not in resolve(RenderSettings()).params()


def test_a_setting_of_another_unit_is_refused_with_its_owner_named_or_left_out_on_request():
    with pytest.raises(ValueError, match="points is a setting of the imperfect bundle method, not of"):
        resolve(RenderSettings(method="perfect", points=16))
    assert resolve(RenderSettings(method="perfect", points=16), inapplicable="drop").settings.options == ()
    with pytest.raises(ValueError, match="unknown setting 'pointz'; the units' settings are .*points"):
        resolve(RenderSettings(pointz=16))
    with pytest.raises(ValueError, match="bundle method must be one of perfect, imperfect, got 'raytraced'"):
        resolve(RenderSettings(method="raytraced"))


@pytest.mark.parametrize(
    "settings, problem",
    [
        (dict(directions=0), "directions must be at least 1, got 0"),
        (dict(frames=2.5), "frames = 2.5 must be a whole number"),
        (dict(rotate_directions=1), "rotate_directions = 1 must be true or false"),
        (dict(time_budget=-1.0), "time_budget must be non-negative and finite seconds, got -1.0"),
        (dict(method="imperfect", splat_scale=0.0), "splat_scale must be positive and finite, got 0.0"),
        (dict(method="imperfect", sampler="sobol"), "sampler must be one of random, stratified, got 'sobol'"),
        (dict(light_samples=-1), "light_samples must be at least 0, got -1"),
        (dict(light_sample_map_size=4), "light_sample_map_size must be at least 8 texels, got 4"),
        # The shaders hash the seed as a 32-bit word: one beyond it would repeat a smaller seed's samples.
        (dict(seed=-1), "seed must be at least 0, got -1"),
        (dict(seed=2**32), "seed must be at most 4294967295, got 4294967296"),
        # A bad value is named before whether its unit is chosen.
        (dict(method="perfect", splat_scale=-1.0), "splat_scale must be positive and finite, got -1.0"),
    ],
)
def test_every_setting_is_checked_by_its_declaration(settings, problem):
    with pytest.raises(ValueError, match=problem):
        resolve(RenderSettings(**settings))


def test_every_unit_declares_its_settings_with_help_and_defaults_in_range():
    assert METHODS.default.name == METHODS.names[0]
    for unit in all_units():
        check_settings(unit.settings())  # the defaults themselves are valid
        for f in declared(unit.settings):
            assert len(f.metadata["help"]) > 10, (unit.name, f.name)
            # A unit may share another's setting only as the same declaration (the bidirectional
            # strategy's light_samples is the eye strategy's, inherited): one meaning, one flag.
            shared = [next(g for g in declared(u.settings) if g.name == f.name) for u in owners(f.name)]
            assert all(g is f for g in shared), f"{f.name} is declared by more than one unit"


def test_a_flag_of_a_unit_the_render_does_not_use_is_a_warning_and_ignored(tmp_path):
    done = run_evalkit(
        "render", "cornell-box", "--method", "perfect", "--splat-scale", "3", "--directions", "2", "--resolution", "8",
        "--width", "8", "--height", "8", "--out", str(tmp_path / "r"), "--json",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "--splat-scale is a setting of the imperfect bundle method, not of this render's perfect" in done.stderr
    assert "splat_scale" not in done.stdout.splitlines()[-1]  # not in the render's provenance
    bad = run_evalkit("render", "cornell-box", "--method", "perfect", "--points", "0", "--out", str(tmp_path / "x"))
    assert bad.returncode == 2 and "argument --points: 0 must be at least 1" in bad.stderr
