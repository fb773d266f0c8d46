"""Procedural models: robots, Mega Bloks, fixtures and tools, written as SDFormat with meshes."""
