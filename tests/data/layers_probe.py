from evalkit.core.errors import InputError  # noqa: F401 -- tests/test_layers.py reads this file; it is never run

def deferred():
    from gpu_impl.bundles import BundleTracer  # noqa: F401
