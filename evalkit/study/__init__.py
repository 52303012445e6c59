"""Studies: a declarative grid of runs (scenes x methods x parameters x seeds), one row of results
per run, resumable, run locally in parallel or on a Dask cluster, ending in an HTML report.

One module per job, each importing only the ones above it in this list:

- `evalkit.study.spec`: the study file (TOML), its validation, and the run parameters (the scene,
  the method and every `gpu_impl.renderer.RenderSettings` field, with the renderer's defaults);
- `evalkit.study.artefacts`: what runs share, made once (Mitsuba references, Embree exact bundles
  and their tracers, the process's GL context);
- `evalkit.study.run`: one run, measured into one row;
- `evalkit.study.executors`: every run of a study (in this process, local processes or Dask),
  the results table and the report.
"""
