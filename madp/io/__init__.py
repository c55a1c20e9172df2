"""Files and processes shared by every job that writes an output directory.

* :mod:`.lock` — one madp job per output directory (``DIR/.madp.lock``, ``fcntl.flock``);
* :mod:`.atomic` — temporary names unique per writer, atomic replacement;
* :mod:`.owned` — ``--overwrite`` removes only the files madp wrote;
* :mod:`.workers` — worker processes that end when their parent dies;
* :mod:`.jsonfile` — a JSON file's value, or a one-line error naming the file;
* :mod:`.checksum` — a file's SHA-256.

Nothing here knows about datasets, models or suites.
"""
