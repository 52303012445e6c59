"""The GLSL implementation of ray-bundle tracing and its Python driver (headless EGL)."""
