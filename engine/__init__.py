"""ragdoll's physics engine: batched rigid bodies, joints and contacts, its step compiled by numba."""
from .allocator import keep_freed_memory
from .builder import WORLD, SceneBuilder, STANDARD_GRAVITY, GRAVITATIONAL_CONSTANT
from .control import Control, apply_impulse
from .core.jit import get_threads, max_threads, set_threads
from .errors import SceneError, SimulationError
from .materials import Material, MaterialTable
from .model import Model
from .settings import ACCURATE, CLOSED_JOINTS, SOFT_JOINTS, Settings
from .shapes import Box, Capsule, Plane, Sphere
from .state import Event, State
from .step import simulate, step

keep_freed_memory()
