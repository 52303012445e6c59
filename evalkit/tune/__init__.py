"""`evalkit tune`: the bundle settings with the least predicted error for a time budget, from
models of time and error fitted to a short calibration sweep of the scene, checked by a render.

For a scene, an image (width x height, B bounces) and a budget of T seconds of render time, the
settings are the candidate (a bundle method, a path strategy and a light visibility: `Candidate`), K
directions, R lines per side, S eye paths per pixel per frame (only with ``--spp tune``), for
imperfect bundles N points and splat scale s, for bidirectional paths V light paths, for exact
shadow maps of light vertices their size M, for imperfect ones their points P and size n, and F
frames.
Each model is fitted per scene and candidate, to the rows of a calibration study (`evalkit.study`,
so its runs are cached in the output folder and a second call with the same budget runs nothing
new):

**Time** of F frames (seconds; `wall_s` of a row), every constant positive (each unit adds its own
terms, declared with it: `gpu_impl.units.TuneTerms`; today's are):

    perfect        t = t_once + F (t0 + t_lists K R^2 + t_paths S + t_dirs K)
    imperfect      t = t_once + F (t0 + t_lists K R^2 + t_paths S + t_points K N + t_nodes K R^2 s^2)
    bidirectional  the method's + F (t_light V + t_connect V S)
    exact maps     + F t_texels (M / 256)^2 V / 8   (eye paths: V = 8, their emitter samples)
    imperfect maps + F (t_ism_points P / 4096 + t_ism_texels (n / 64)^2) V / 8

t_once is what a render does once (a static scene's shadow maps, reading the images back); t0 what
a frame does that does not depend on the bundles (G-buffer, emitter samples, the bounce passes at
this image size); K R^2 are the lists, S the eye paths, K the per-direction draw (perfect), K N the
splat points and K R^2 s^2 the splat nodes (a splat covers about s^2 A / (4 r^2) R^2 / N lines); V
the light paths' B V vertices, each a shadow map (exact or imperfect: the cost of drawing its
triangles is in t_light, fitted per candidate; exact maps' texels are t_texels, imperfect maps'
points and texels t_ism_points and t_ism_texels), and V S a connection from every eye vertex to
each.

**Error** (the chosen metric, e.g. relMSE of the indirect image against the Mitsuba reference):

    perfect        E = b (64 / R)^2 + (v 16 / S + w / K) / F
    imperfect      E = the same + h exp(-c s^q) + g s^2 (16384 / N)
    bidirectional  the method's + u / (F V)
    exact maps     + m(M), measured
    imperfect maps + i(P, n), measured

b (64 / R)^2 is the squared O(1/R) bias of the line a path takes (docs/results/decisions.toml: four-lines); v 16 /
(F S) the paths' variance; w / (F K) what a frame's K shared directions add (the directions study),
which more paths in the same frame do not take away; h
the holes of the splat points, with the hole model's shape for their sampler (c, q:
studies/hole_vs_splat.toml); g s^2 / N the splats' overhang, which grows with their radius squared;
u / (F V) what the connections add, shared by a frame's pixels, and so, like w, not falling with S;
m(M) the squared bias of a shadow map's texel (light leaked or hidden beside contacts, a band a
texel or so wide), and t_texels the maps' texels, which on atrium are 40 % of a bidirectional
frame at M = 256 and next to nothing at 32 (gpu_impl/visibility/exact.py); i(P, n) what imperfect
maps change against exact maps for the same light vertices (light leaked through holes and the
slope-scaled bias of coarse texels, light hidden by splats), which falls with P and, at each P,
rises or falls with n (gpu_impl/visibility/imperfect.py). m(M) and i(P, n) are measured, not
fitted: renders at each M (each P and n) with the same seed (the same paths) differ by their maps'
bias and noise, and at two seeds (`BIAS_SEEDS`) their differences from a render without that bias
(at the largest M; with exact maps) give an unbiased estimate of what each setting adds to the
metric in the limit, the cross term with every other bias included (`calibration.measure_bias`; at
least 0). A calibration run's noise hides that bias where a close-up of a contact shows it (+9 %
at M = 32), and it follows no one power of M: fitted, m followed the noise. Renders can measure a
bias so only under the metrics that square errors (mse, relmse); under the others these settings
stay at their defaults, with a warning (`models.unmeasured_axes`). Eye paths in a scene without
emissive triangles draw no map: M, P and n stay at their defaults for them (`models.idle_axes`),
and candidates that differ only in the kind of map they never draw are tuned once.
Each candidate fits its own v: the eye paths' variance is what the light paths take away. The
shared terms are why S can matter to the choice of strategy: on atrium which strategy leads at
matched time moves with S (docs/results/decisions.toml: eye-paths-a-frame). With ``--spp tune``
the calibration runs take S in a cycle of their own (`CALIBRATION_SPP`); the default keeps S = 16,
whose recommendations measured as good or better (docs/reference/studies.md: the same calibration time spread over
one more setting fits it less well). ``--pin`` holds any other setting the optimiser chooses at a
value (`calibration.pins`); its calibration runs still vary it, which its terms need.

Both fits minimise the squared log residuals by gradient descent with Dr.Jit's automatic
differentiation (`evalkit.metrics.fitting`). The calibration costs about ``calibration_share`` times
the budget: each of its runs renders frames until its share of that time is spent (the renderer's
``time_budget``), at least one, so a larger budget calibrates with more frames, where the bias
terms it must then predict show through the noise. Half of that time goes to runs spread over the
settings; the other half renders each candidate's first optimum, which then anchors the refit
(`SPREAD`). The renders that measure a bias term (one or two frames each) come on top. The
optimisation evaluates, per candidate, every setting of its grid (`models.GRID` and the units'
axes), each with the whole frames that fill the budget, F = floor((T - t_once) / (time per
frame)), and takes the least predicted error: a continuous optimum rounded to the grid (the first
version) missed where whole frames matter. The check renders each candidate's optimum and
measures its time and error (an optimum that overran the budget is rendered again with the frames
its measured time fits); the recommendation is the one with the least measured error of those
that kept the budget (within `BUDGET_TOLERANCE`, a run's timing noise; of all, with a warning,
where none did; without the check: the least predicted error). Between
candidates the choice is left to the measurement because the models' residuals are as large as the
predicted differences: at atrium's 10 s the perfect optimum was predicted 6 % better than the
imperfect one and measured 26 % worse.

One module per job: `evalkit.tune.models` (the terms and their fit), `evalkit.tune.optimise` (the
least predicted error within a budget), `evalkit.tune.calibration` (the runs and `tune`),
`evalkit.tune.report` (report.html).
"""

from evalkit.tune.calibration import CALIBRATION_SHARE, calibration_grid, compare_with_grid, tune
from evalkit.tune.models import GRID, TUNE_METRICS, Candidate, Model, axes, fit_model
from evalkit.tune.optimise import Recommendation, optimise
from evalkit.tune.report import bias_text, settings_text, write_tune_report

__all__ = [
    "CALIBRATION_SHARE",
    "GRID",
    "Candidate",
    "TUNE_METRICS",
    "Model",
    "Recommendation",
    "axes",
    "bias_text",
    "calibration_grid",
    "compare_with_grid",
    "fit_model",
    "optimise",
    "settings_text",
    "tune",
    "write_tune_report",
]
