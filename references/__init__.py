"""Ground truths: Mitsuba 3 path-traced reference images and Embree exact-visibility bundles."""
