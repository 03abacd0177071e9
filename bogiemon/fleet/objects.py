"""A fleet's recordings in an object store: `fleet analyze s3://bucket/prefix`, and any fsspec URL.

Gateways upload their recordings to an object store (S3 or one that speaks its protocol) under
the tree of docs/fleet-formats.md section 1. This is a thin layer over the local reading, and every
byte of an object passes a bounded read:

- the tree is listed once (fsspec's find, every object under the prefix with its size and time);
  names are held to the local tree's rules (fleet/layout.py), and what is no recording is skipped
  and named as there;
- the small files (fleet.toml, each wagon's .toml files) are fetched into a private scratch folder
  and read there as local ones, with their kinds' bounds (a config's include names a file beside
  it, which is fetched with it);
- a recording is fetched when its task analyses it (fetch_recording), on the Dask worker that runs
  the task, into a private temporary file under its own name, which the readers then open as a
  local recording through drivers/files.py's bounded open (size, gzip inflation and line bounds);
  the file is removed when the task is done with it.

A bounded read: the object's listed size is checked against its kind's bound before a byte is read,
and at most that many bytes (and one more, to notice) are read whatever the store sends (an object
replaced by a larger one between the listing and the read is refused, naming it). Credentials and
the endpoint come from the store's own environment: for S3 the AWS variables (AWS_ACCESS_KEY_ID,
AWS_SECRET_ACCESS_KEY, AWS_ENDPOINT_URL for a compatible server) or fsspec's FSSPEC_S3_* ones.

ASSUMED (the readers are being reworked beside this): a reader takes a local path and opens it
through drivers/files.py's bounded open; the local copy is what makes that true of an object. When
the readers take an opened bounded file (an UntrustedFile), fetch_recording can hand over the same
copy's descriptor instead of its path.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import os
import posixpath
import shutil
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bogiemon.drivers.files import size_text
from bogiemon.drivers.recording_format import RECORDING_FILE, RecordingError

CHUNK_BYTES = 1 << 20
LOCAL_SCHEMES = ("", "file", "local")
# A fleet's small files (fleet.toml, configs, calibrations): what the local tree's kinds allow.
SMALL_FILE_BYTES = 1 << 20


class ObjectStoreError(ValueError):
    """The object store cannot be listed or read (no such bucket, no credentials, no package for
    its protocol): one line naming the URL and what to do."""


def is_url(location: str | os.PathLike[str]) -> bool:
    """Whether a FLEET names an object store (a URL of a scheme other than file://)."""
    text = os.fspath(location)
    scheme, sep, _ = text.partition("://")
    return bool(sep) and scheme.lower() not in LOCAL_SCHEMES and scheme.isascii() and scheme.replace("+", "").replace("-", "").isalnum()


@dataclass(frozen=True)
class ObjectInfo:
    key: str  # the object's path relative to the fleet's prefix ("W1/2026-11-02/060000_run.csv.gz")
    size_bytes: int
    mtime_ns: int  # the object's modification time (0 when the store gives none)


@dataclass(frozen=True)
class Store:
    """A fleet's prefix in an object store: its URL, its fsspec filesystem and the prefix's path."""

    url: str  # as the user named it, without a trailing slash
    protocol: str
    root: str  # the prefix as the filesystem names it ("bucket/prefix")

    @property
    def fs(self) -> Any:
        return _filesystem(self.protocol, self.url)

    def url_of(self, key: str) -> str:
        return f"{self.url}/{key}"


def _filesystem(protocol: str, url: str) -> Any:
    try:
        import fsspec
    except ImportError:
        raise ObjectStoreError(f"{url}: reading an object store needs fsspec: pip install 'bogiemon[fleet]'") from None
    try:
        return fsspec.filesystem(protocol)
    except (ImportError, ValueError) as exc:
        extra = "pip install 'bogiemon[fleet]' (S3)" if protocol in ("s3", "s3a") else f"install fsspec's package for {protocol}://"
        raise ObjectStoreError(f"{url}: no filesystem for {protocol}:// ({' '.join(str(exc).split())[:200]}); {extra}") from None


def open_store(url: str) -> Store:
    url = url.rstrip("/")
    protocol, _, rest = url.partition("://")
    if not rest.strip("/"):
        raise ObjectStoreError(f"{url}: name a bucket and prefix, e.g. s3://bucket/fleet")
    store = Store(url=url, protocol=protocol.lower(), root=rest.strip("/"))
    store.fs  # noqa: B018 - the package for the protocol is there, or one line says which
    return store


def _time_ns(info: dict[str, Any]) -> int:
    """An object's modification time from what its store lists (S3: LastModified; local: mtime)."""
    for key in ("LastModified", "last_modified", "mtime", "updated", "created"):
        value = info.get(key)
        if isinstance(value, dt.datetime):
            return int(value.timestamp() * 1e9)
        if isinstance(value, int | float):
            return int(value * 1e9)
        if isinstance(value, str):
            with contextlib.suppress(ValueError):
                return int(dt.datetime.fromisoformat(value.replace("Z", "+00:00")).timestamp() * 1e9)
    return 0


def list_objects(store: Store) -> list[ObjectInfo]:
    """Every object under the prefix, in key order; ObjectStoreError when it cannot be listed or holds nothing."""
    try:
        # An fsspec filesystem is shared by every scan of the process and may answer from its listings
        # cache (s3fs's find lists afresh; not every filesystem does): no cached listing hides an upload.
        store.fs.invalidate_cache(store.root)
        found = store.fs.find(store.root, detail=True, withdirs=False)
    except FileNotFoundError:
        found = {}
    except (OSError, ValueError, PermissionError) as exc:
        raise ObjectStoreError(f"{store.url}: cannot be listed ({' '.join(str(exc).split())[:300]}); check the URL and the store's credentials") from None
    out = []
    prefix = store.root + "/"
    for name, info in found.items():
        name = name.strip("/")
        if info.get("type", "file") != "file" or not name.startswith(prefix):
            continue
        size = info.get("size") or info.get("Size") or 0
        out.append(ObjectInfo(name[len(prefix) :], int(size), _time_ns(info)))
    if not out:
        raise ObjectStoreError(f"{store.url}: no such fleet (no object under the prefix; expected <wagon-id>/<YYYY-MM-DD>/ recordings)")
    return sorted(out, key=lambda o: o.key)


def fetch(store: Store, key: str, target: Path, max_bytes: int, error: type[Exception], size_bytes: int | None = None) -> Path:
    """Copy one object to target (a new local file), reading at most max_bytes of it; `error`
    naming the object's URL when it is larger (listed, or as read), missing or unreadable."""
    url = store.url_of(key)
    if size_bytes is not None and size_bytes > max_bytes:
        raise error(f"{url}: larger than {size_text(max_bytes)}; is this the right object?")
    copied = 0
    try:
        with store.fs.open(posixpath.join(store.root, key), "rb") as src, open(target, "xb") as dst:
            while chunk := src.read(min(CHUNK_BYTES, max_bytes + 1 - copied)):
                copied += len(chunk)
                if copied > max_bytes:
                    raise error(f"{url}: grew past {size_text(max_bytes)} while it was read; is this the right object?")
                dst.write(chunk)
    except FileNotFoundError:
        raise error(f"{url}: no longer in the store (removed since it was listed?)") from None
    except OSError as exc:
        raise error(f"{url}: cannot be read ({' '.join(str(exc).split())[:300]})") from None
    return target


@contextlib.contextmanager
def scratch(prefix: str = "bogiemon-objects-") -> Iterator[Path]:
    """A private folder (mode 700) for local copies, removed with everything in it afterwards."""
    folder = Path(tempfile.mkdtemp(prefix=prefix))
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)


@contextlib.contextmanager
def fetch_recording(url: str, size_bytes: int | None = None) -> Iterator[Path]:
    """A recording object as a local file under its own name (its readers tell a format by it),
    for the duration of the block; RecordingError naming the URL when it cannot be fetched."""
    store_url, _, key = url.rpartition("/")
    store = Store(url=store_url, protocol=url.partition("://")[0].lower(), root=store_url.partition("://")[2].strip("/"))
    with scratch("bogiemon-recording-") as folder:
        yield fetch(store, key, folder / key, RECORDING_FILE.max_bytes, RecordingError, size_bytes)
