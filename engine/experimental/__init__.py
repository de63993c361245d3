"""Experimental, frozen code: not selectable by any job, kept only so its bench table keeps working.

- traverse_linked.py, linked_mesh.py, linked_media.py: surfaces linked to the cells they overlap (the
  paper's Appendix C), measured against the terrain-following mesh by bench/linked_surfaces.py and
  tests/mesh/test_linked_surfaces.py. The kernel is a fork of the main traversal loop taken before the
  kernel-contract refactor: it lacks the main loop's slide, ping-pong and graze fixes, has no field
  accumulation and no wind. It is frozen (no fixes are ported to it); jobs always use kernels/traverse.py.
"""
