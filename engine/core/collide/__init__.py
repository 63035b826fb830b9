"""Collision detection kernels: broad phase and narrow phase, one pair at a time.

* :mod:`.broadphase`: world AABBs of bodies and their overlap test;
* :mod:`.plane`, :mod:`.round`, :mod:`.box_round`, :mod:`.boxes`: one
  scalar kernel per canonical shape pair (plane-sphere, ..., box-box) that
  returns one pair's manifold as a tuple (:mod:`.manifold`, which also
  stores it into output arrays at a row), with helpers in :mod:`.geometry`;
* :mod:`.narrowphase`: the pair kind codes and a world's narrow phase,
  which calls each pair's kernel by its code;
* :mod:`.world`: a step's detection of one world (AABBs grown by the
  speculative reach, the overlap test over the candidate pairs, the narrow
  phase) and its batched and serial loops over worlds.

The numpy-facing functions of :mod:`engine.collision` wrap these kernels.
Units: metres.
"""

from .manifold import INVALID_SEPARATION, MAX_POINTS
from .narrowphase import KIND_CODES, narrow_rows, narrow_world
from .world import detect, detect_batch, detect_serial, detect_world, gather_rows

__all__ = ["INVALID_SEPARATION", "MAX_POINTS", "KIND_CODES", "narrow_rows", "narrow_world", "detect",
           "detect_batch", "detect_serial", "detect_world", "gather_rows"]
