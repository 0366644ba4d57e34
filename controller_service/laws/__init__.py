"""Control laws: pure functions of (time, state, reference, memory, parameters), no I/O."""
