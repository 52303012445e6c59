"""Light visibilities (how light vertices see the scene): one module each, registered in gpu_impl/registry.py."""
