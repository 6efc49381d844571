"""MuJoCo simulation backend. Renders through EGL unless MUJOCO_GL names another (twin.rendering)."""
