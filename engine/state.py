"""Batched dynamic state: every array has a leading world axis of length W.

A state holds positions (W, N, 3) in m, orientations (W, N, 4) as unit
quaternions (w, x, y, z), linear velocities (W, N, 3) in m/s and world-frame
angular velocities (W, N, 3) in rad/s, a step counter per world, broken-flags
of springs and joints, and the solver's warm-start caches. One world (W = 1)
is just the smallest batch.

States are plain containers: ``copy``, ``select`` (a subset of worlds, as a
new state), ``worlds`` (a slice of them, as views), ``assign`` (write another state into a subset of worlds) and
``concatenate`` are all array operations along the world axis.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .core.world import nonfinite


@dataclass(frozen=True)
class Event:
    """Something that happened during a step: a spring or joint broke.

    kind: "spring_broken" or "joint_broken"; name: the item's name;
    world: world index; step: the step count at which it happened (the step
    that produced it is ``step``; time = step * dt seconds).
    """

    kind: str
    name: str
    world: int
    step: int
    time: float


#: Arrays every state carries, with their trailing shape relative to the model.
CORE_FIELDS = ("position", "orientation", "velocity", "angular_velocity", "step")


@dataclass
class State:
    """Dynamic part of W worlds. Arrays are indexed [world, item, ...]."""

    arrays: dict = field(default_factory=dict)
    events: list = field(default_factory=list)

    # Named access to the arrays -------------------------------------------------
    def __getattr__(self, name):
        arrays = self.__dict__.get("arrays")
        if arrays is not None and name in arrays:
            return arrays[name]
        raise AttributeError(f"State has no field {name!r}")

    def __setattr__(self, name, value):
        if name in ("arrays", "events"):
            object.__setattr__(self, name, value)
        elif name in self.arrays:
            value = np.asarray(value, dtype=self.arrays[name].dtype)
            if value.shape != self.arrays[name].shape:
                raise ValueError(
                    f"state.{name} has shape {self.arrays[name].shape}, cannot assign shape {value.shape}"
                )
            self.arrays[name][...] = value
        else:
            raise AttributeError(f"State has no field {name!r}")

    @property
    def num_worlds(self) -> int:
        return self.arrays["position"].shape[0]

    def copy(self) -> "State":
        return State({k: v.copy() for k, v in self.arrays.items()}, list(self.events))

    def select(self, worlds) -> "State":
        """A new state holding only ``worlds`` (indices, slice or boolean mask);
        its events are those of the selected worlds, numbered as in the new state."""
        idx = world_index(worlds, self.num_worlds)
        picked = np.arange(self.num_worlds)[idx]  # old world of each new one (negative indices resolved)
        events = [replace(e, world=new) for new, old in enumerate(picked.tolist())
                  for e in self.events if e.world == old]
        return State({k: v[idx].copy() for k, v in self.arrays.items()}, events)

    def worlds(self, lo: int, hi: int) -> "State":
        """Worlds [lo, hi) as a state of views: stepping it steps them here
        (without the events: a step of it reports its own)."""
        return State({k: v[lo:hi] for k, v in self.arrays.items()})

    def assign(self, worlds, other: "State") -> None:
        """Write ``other``'s worlds into ``worlds`` of this state in place.

        ``other`` has either as many worlds as are selected, or one world,
        which is then copied into each selected world.
        """
        idx = world_index(worlds, self.num_worlds)
        selected = np.arange(self.num_worlds)[idx].size
        if other.num_worlds not in (1, selected):
            raise ValueError(f"cannot assign a state of {other.num_worlds} worlds to {selected} selected "
                             f"worlds: give one world or as many as are selected")
        for k, v in self.arrays.items():
            if k not in other.arrays:
                raise ValueError(f"cannot assign: the other state lacks field {k!r}")
            if other.arrays[k].shape[1:] != v.shape[1:]:
                raise ValueError(f"cannot assign: field {k!r} holds {other.arrays[k].shape[1:]} per world in "
                                 f"the other state and {v.shape[1:]} here (a state of another model?)")
        for k, v in self.arrays.items():
            v[idx] = other.arrays[k]

    def nonfinite_worlds(self) -> np.ndarray:
        """Indices of worlds with any NaN or infinite position or velocity."""
        bad = np.empty(self.num_worlds, dtype=bool)
        nonfinite(self.position, self.orientation, self.velocity, self.angular_velocity, bad)
        return np.flatnonzero(bad)

    @staticmethod
    def concatenate(states) -> "State":
        states = list(states)
        keys = states[0].arrays.keys()
        offsets = np.cumsum([0] + [s.num_worlds for s in states])
        events = [replace(e, world=e.world + int(lo)) for s, lo in zip(states, offsets) for e in s.events]
        return State({k: np.concatenate([s.arrays[k] for s in states], axis=0) for k in keys}, events)

    def equal(self, other: "State") -> bool:
        """Bit-for-bit equality of every array."""
        return self.arrays.keys() == other.arrays.keys() and all(
            np.array_equal(v, other.arrays[k], equal_nan=True) for k, v in self.arrays.items()
        )

    def nbytes(self) -> int:
        return sum(v.nbytes for v in self.arrays.values())


# The core arrays are also properties of State: found before __getattr__,
# a lookup costs about a fifth of its (210 against 1,070 ns), and the solver
# reads them hundreds of times a step.
def _core_array(name):
    def get(self):
        try:
            return self.arrays[name]
        except KeyError:
            raise AttributeError(f"State has no field {name!r}") from None
    return property(get, doc=f"The state's {name!r} array (see the module docstring for units).")


for _name in CORE_FIELDS:
    setattr(State, _name, _core_array(_name))


def world_index(worlds, num_worlds):
    """Worlds given as indices (negative ones count from the end), a slice or
    a boolean mask of ``num_worlds``, as an index for the state's arrays."""
    if isinstance(worlds, slice):
        return worlds
    arr = np.asarray(worlds)
    if arr.dtype == bool:
        if arr.shape != (num_worlds,):
            raise ValueError(f"world mask must have shape ({num_worlds},), got {arr.shape}")
        return np.flatnonzero(arr)
    arr = arr.astype(np.int64).reshape(-1)
    if arr.size and (arr.min() < -num_worlds or arr.max() >= num_worlds):
        raise IndexError(f"world index out of range for {num_worlds} worlds: {arr}")
    return arr
