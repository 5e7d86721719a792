"""Pick an offscreen GL backend before any test imports MuJoCo's rendering."""

from abyss.stations.simulation.rendering import choose_gl_backend

choose_gl_backend()
