"""Bundle methods: one module each, registered in gpu_impl/registry.py."""
