"""Reading and planning scenes: a stage's cameras, lights and bound meshes, what each bound
material needs (plan, reach), the shots, the per-mesh bindings and ``usdbtf build``."""
