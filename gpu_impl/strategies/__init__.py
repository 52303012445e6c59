"""Path strategies: one module each, registered in gpu_impl/registry.py."""
