"""The hostile inputs of the third attack, as `bogiemon replay` and `analyze` meet them in a real
process: refused in one line, exit 2, the process's peak resident memory under the gateway
unit's 200 MiB (the issue's cases: a 1.9 MB Parquet file of pages inflating to 512 MiB each that
peaked at 1.66 GB; a 1 MB .log.gz that reached 2.1 GB)."""

from __future__ import annotations

import gzip
import subprocess
import sys
from pathlib import Path

import pytest

MAX_RSS_MIB = 200
# The command in a child of a small Python process, whose RUSAGE_CHILDREN is then that command's alone.
_MEASURE = (
    "import resource, subprocess, sys; r = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
    "sys.stdout.write(r.stderr); print(f'rc={r.returncode} rss_kib={resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss}')"
)
# The Parquet: each column one page of 64 Mi zeros (512 MiB), 66 kB in all with zstd (11 s to
# write); main at dff7856 peaked at 2.2 GB replaying it.
_WRITE_PARQUET_BOMB = """
import struct, sys, numpy as np, pyarrow as pa, pyarrow.parquet as pq
n = 64 << 20
zeros = pa.array(np.zeros(n))
pq.write_table(pa.table({"time_s": zeros, "a1": zeros, "a2": zeros, "a3": zeros}), sys.argv[1], compression="zstd",
               compression_level=1, use_dictionary=False, data_page_size=1 << 30, max_rows_per_page=n, row_group_size=n, write_statistics=False)

def varint(value, width):  # a zigzag varint, padded to width bytes as Thrift readers accept
    z = value << 1
    out = bytearray()
    for i in range(width):
        out.append((z & 0x7F) | (0x80 if i < width - 1 else 0))
        z >>= 7
    assert z == 0
    return bytes(out)

# The footer lies: 1000 rows, not 64 Mi, in the file and its row group, and 64 kB in the group;
# the pages stay as they are.
data = bytearray(open(sys.argv[1], "rb").read())
length = struct.unpack_from("<I", data, len(data) - 8)[0]
footer = bytes(data[len(data) - 8 - length : len(data) - 8])
footer = footer.replace(varint(n, 4), varint(1000, 4))
total = pq.ParquetFile(sys.argv[1]).metadata.row_group(0).total_byte_size
footer = footer.replace(varint(total, 5), varint(64000, 5))  # and 64 kB in its row group
data[len(data) - 8 - length : len(data) - 8] = footer
open(sys.argv[1], "wb").write(bytes(data))
"""


def measured(*args: str) -> tuple[int, float, str]:
    """(exit status, peak RSS in MiB, stderr) of `bogiemon ARGS...` run as a real process."""
    out = subprocess.run(
        [sys.executable, "-c", _MEASURE, sys.executable, "-m", "bogiemon", *args], capture_output=True, text=True, timeout=600, check=True
    ).stdout
    last = out.strip().splitlines()[-1]
    rc, rss = (field.split("=")[1] for field in last.split())
    return int(rc), int(rss) / 1024, out


@pytest.fixture(scope="module")
def parquet_bomb(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("bomb") / "bomb.parquet"
    subprocess.run([sys.executable, "-c", _WRITE_PARQUET_BOMB, str(path)], check=True, timeout=600)
    return path


@pytest.mark.slow
@pytest.mark.parametrize("command", ["replay", "analyze"])
def test_a_parquet_of_pages_inflating_to_512_mib_is_refused_within_200_mib(parquet_bomb: Path, command: str) -> None:
    assert parquet_bomb.stat().st_size < 4 << 20
    rc, rss_mib, err = measured(command, str(parquet_bomb))
    assert rc == 2 and "column time_s: a page at byte 4 inflates to 536870921 bytes" in err, err
    assert len(err.strip().splitlines()) == 2  # the one error line, and the measure's own
    assert rss_mib < MAX_RSS_MIB


@pytest.mark.slow
@pytest.mark.parametrize("command", ["replay", "analyze"])
def test_a_1_mb_log_gz_of_one_endless_line_stays_within_200_mib(tmp_path: Path, command: str) -> None:
    path = tmp_path / "bomb.log.gz"
    with gzip.open(path, "wb", compresslevel=9) as f:
        f.write(b"(1764500000.000000) can0 100#")
        for _ in range(1024):
            f.write(b"0" * (1 << 20))  # 1 GiB of one line, a megabyte compressed
    assert path.stat().st_size < 3 << 20
    rc, rss_mib, err = measured(command, str(path))
    assert rc == 2 and "(a compression bomb?)" in err, err
    assert rss_mib < MAX_RSS_MIB
