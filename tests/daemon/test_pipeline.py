"""The pipeline's threads (daemon/pipeline.py): named in the kernel, where `top -H` shows them."""

from __future__ import annotations

import threading
from pathlib import Path

from bogiemon.daemon.pipeline import name_os_thread


def test_a_thread_named_for_the_kernel_shows_its_name_in_proc() -> None:
    seen: list[str] = []

    def run() -> None:
        name_os_thread("bogiemon-source-and-more")  # longer than the kernel's 15 bytes
        seen.append(Path(f"/proc/self/task/{threading.get_native_id()}/comm").read_text().strip())

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    assert seen == ["bogiemon-source"]
    assert Path(f"/proc/self/task/{threading.get_native_id()}/comm").read_text().strip() != "bogiemon-source"
