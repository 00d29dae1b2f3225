"""Demonstration data: the file schema and io, the datasets a run needs and their manifest, generation by a
task's scripted team, varied humans, and import of your own files."""
