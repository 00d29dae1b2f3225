"""cogail-jax: Co-GAIL in JAX."""
import os as _os

# Every HDF5 file this package writes goes to a temporary name of its own process and is renamed into place, so a
# reader only ever sees whole files and no two writers share one: HDF5's own file locks guard nothing here. They do
# fail spuriously ("unable to lock file, errno = 11"), as `cogail data` did on a GPU while its training programs
# compiled beside it: a child process started while a file is open inherits its descriptor and the lock. A user's
# setting is kept.
_os.environ.setdefault("HDF5_USE_FILE_LOCKING", "FALSE")

__version__ = "0.1.0"
