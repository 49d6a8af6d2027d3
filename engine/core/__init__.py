"""What every other engine package stands on: the scene description (`scene`), kernel
compilation (`jit`, `kernel_cache`, `kernel_watch`, `features`), random streams and
sampling, affine maps, thread pools and the memory budget. Imports nothing else of
the engine."""
