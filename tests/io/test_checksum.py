"""A file's SHA-256 (madp/io/checksum.py): read in chunks; an unreadable file is one line naming it."""

import hashlib

import pytest

from madp.errors import InputError
from madp.io.checksum import sha256_file


def test_sha256_file_reads_in_chunks_and_names_unreadable_files(tmp_path):
    f = tmp_path / "blob.bin"
    data = bytes(range(256)) * 5
    f.write_bytes(data)
    assert sha256_file(f, chunk_bytes=7) == hashlib.sha256(data).hexdigest()
    with pytest.raises(InputError) as e:
        sha256_file(tmp_path)
    assert str(e.value) == f"{tmp_path}: cannot read file (Is a directory)"
