"""drivers/files.py: one way to open a file from outside, its bounds, and one error naming the file."""

from __future__ import annotations

import gzip
import os
import re
import threading
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.drivers.files import FileKind, UntrustedFileError, open_untrusted, read_untrusted


class OwnError(ValueError):
    """A caller's own user error."""


KIND = FileKind(
    name="test file", description="a test file is text", max_bytes=1 << 16, too_large="use a smaller one",
    gzip=True, max_inflated_bytes=1 << 30, max_inflate_ratio=100.0, max_line_bytes=64,
)  # fmt: skip


def test_the_error_is_the_callers_class_naming_the_file_and_what_it_is(tmp_path: Path) -> None:
    with pytest.raises(OwnError) as info:
        open_untrusted(tmp_path, KIND, OwnError)
    assert str(info.value) == f"{tmp_path}: a folder; a test file is text"


def test_without_an_error_class_the_modules_own_is_raised(tmp_path: Path) -> None:
    with pytest.raises(UntrustedFileError, match=r"missing: cannot read the test file: No such file or directory$"):
        open_untrusted(tmp_path / "missing", KIND)


def test_a_device_is_refused_without_reading_it() -> None:
    with pytest.raises(OwnError) as info:
        open_untrusted("/dev/zero", KIND, OwnError)
    assert str(info.value) == "/dev/zero: not a regular file; a test file is text"


def test_a_fifo_nobody_writes_to_is_refused_without_blocking(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    outcome: list[BaseException] = []
    worker = threading.Thread(target=lambda: outcome.append(pytest.raises(OwnError, open_untrusted, fifo, KIND, OwnError).value))
    worker.start()
    worker.join(10.0)
    assert not worker.is_alive(), "open_untrusted blocked on a FIFO"
    assert str(outcome[0]) == f"{fifo}: not a regular file; a test file is text"


def test_a_nul_in_the_name_is_no_file_name() -> None:
    with pytest.raises(OwnError, match=r"^'a\\x00b': not a file name$"):
        open_untrusted("a\x00b", KIND, OwnError)


def test_a_file_larger_than_the_cap_is_refused_before_a_byte_is_read(tmp_path: Path) -> None:
    path = tmp_path / "big"
    path.write_bytes(b"x" * ((1 << 16) + 1))
    with pytest.raises(OwnError) as info:
        open_untrusted(path, KIND, OwnError)
    assert str(info.value) == f"{path}: larger than 64 KiB; use a smaller one"


def test_a_file_that_grows_past_the_cap_while_read_is_cut_there(tmp_path: Path) -> None:
    path = tmp_path / "growing"
    path.write_bytes(b"x" * 1000)
    with open_untrusted(path, KIND, OwnError) as f:
        with path.open("ab") as writer:  # a logger still appending
            writer.write(b"y" * (1 << 16))
        with pytest.raises(OwnError, match=r"growing: grew past 64 KiB while it was read; use a smaller one$"):
            f.read_whole()
        assert f.tell() == (1 << 16) + 1


def test_a_file_of_exactly_the_cap_is_read_whole(tmp_path: Path) -> None:
    path = tmp_path / "full"
    path.write_bytes(b"z" * (1 << 16))
    assert read_untrusted(path, KIND, OwnError) == b"z" * (1 << 16)


def test_gzip_is_read_decompressed_by_its_magic_whatever_the_name(tmp_path: Path) -> None:
    path = tmp_path / "plain-name.txt"
    path.write_bytes(gzip.compress(b"hello\n"))
    with open_untrusted(path, KIND, OwnError) as f:
        assert f.compressed and f.read_whole() == b"hello\n"


def test_a_kind_without_gzip_reads_the_compressed_bytes_as_they_are(tmp_path: Path) -> None:
    path = tmp_path / "x.gz"
    path.write_bytes(gzip.compress(b"hello\n"))
    kind = FileKind(name="config file", description="text", max_bytes=1 << 16, too_large="smaller")
    assert read_untrusted(path, kind, OwnError) == path.read_bytes()


def test_a_compression_bomb_is_refused_after_its_bound_not_inflated_whole(tmp_path: Path) -> None:
    path = tmp_path / "bomb.gz"
    path.write_bytes(gzip.compress(b"\n" * (64 << 20), compresslevel=9))  # 64 MiB in about 64 KiB
    with open_untrusted(path, KIND, OwnError) as f:
        bound = f.max_read_bytes
        with pytest.raises(OwnError) as info:
            while f.read(1 << 16):
                pass
        assert f.tell() == bound + 1  # stopped one byte past the bound
    assert bound == max(1 << 20, int(100 * path.stat().st_size)) < (64 << 20)
    assert str(info.value).startswith(f"{path}: decompresses to more than {bound >> 10} KiB (100 times its compressed size, or 1 GiB)")


def test_a_gzip_stream_cut_short_is_one_error_naming_the_file(tmp_path: Path) -> None:
    path = tmp_path / "cut.gz"
    path.write_bytes(gzip.compress(os.urandom(20000))[:-100])
    with pytest.raises(OwnError) as info:
        read_untrusted(path, KIND, OwnError)
    assert str(info.value) == (
        f"{path}: the compressed test file is cut short (its gzip stream ends early: a partial copy or upload?); copy it again"
    )


def test_a_damaged_gzip_stream_is_one_error_naming_the_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.gz"
    data = bytearray(gzip.compress(os.urandom(20000)))
    data[5000:5064] = bytes(64)
    path.write_bytes(bytes(data))
    with pytest.raises(OwnError, match=rf"^{re.escape(str(path))}: not a readable gzip file \(.+\); the compressed test file is damaged: copy it again$"):
        read_untrusted(path, KIND, OwnError)


def test_a_line_longer_than_the_bound_is_refused_naming_it_after_reading_that_much(tmp_path: Path) -> None:
    path = tmp_path / "long"
    path.write_bytes(b"short\n" + b"x" * 65 + b"\n" + b"y" * 60000)
    with open_untrusted(path, KIND, OwnError) as f:
        lines = f.lines(chunk_bytes=16)
        assert next(lines) == (1, b"short")
        with pytest.raises(OwnError) as info:
            next(lines)
        assert f.tell() < 6 + 65 + 1 + 16  # not the 60000 bytes after it
    assert str(info.value) == f"{path}: line 2: longer than 64 bytes; a test file is text: is this the right file?"


def test_a_line_of_exactly_the_bound_is_given(tmp_path: Path) -> None:
    path = tmp_path / "edge"
    path.write_bytes(b"x" * 64 + b"\r\n" + b"y" * 64)
    with open_untrusted(path, KIND, OwnError) as f:
        assert list(f.lines(chunk_bytes=7)) == [(1, b"x" * 64), (2, b"y" * 64)]


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.sampled_from([b"a", b"bc", b"1,2,3", b"", b" "]), max_size=30),
    st.lists(st.sampled_from([b"\n", b"\r", b"\r\n"]), min_size=30, max_size=30),
    st.booleans(),
    st.integers(1, 9),
)
def test_lines_split_at_cr_lf_and_crlf_across_any_chunking(tmp_path_factory, texts, breaks, last_break: bool, chunk_bytes: int) -> None:
    data = b"".join(t + b for t, b in zip(texts, breaks, strict=False))
    if texts and not last_break:
        data = data[: -len(breaks[len(texts) - 1])]
    path = tmp_path_factory.mktemp("lines") / "f"
    path.write_bytes(data)
    expected = re.split(rb"\r\n|\r|\n", data)
    if expected and expected[-1] == b"":
        expected.pop()  # a final line break ends the last line; it starts none
    with open_untrusted(path, KIND, OwnError) as f:
        assert list(f.lines(chunk_bytes=chunk_bytes)) == list(enumerate(expected, start=1))
