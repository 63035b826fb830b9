"""Force effects: each module is one effect, compiled into a model only when the
scene declares it, so a scene pays nothing for what it lacks.

An effect object holds its parameters as arrays; the step's forces and
implicit velocity updates are compiled kernels (:mod:`engine.core.effects`)
reading the arrays ``engine.core.effects.compile_effects`` gathers from these
objects at model build. An effect may also define:

``end_of_step(model, state, events)``
    once per step, after the positions are final (breaking);
``potential(model, state)``
    its potential energy per world in J (diagnostics).
"""
