"""Real renderers run in other Pythons: Storm through Hydra (hydra) and Cycles/OSL through
the Blender add-on (cycles)."""
