"""The suite's compile scheduler (tests/conftest.py's warm_among_workers): each part once among the workers, a
part after what it needs, and the extra parts taken by a worker that would otherwise wait."""

import threading
import time

from tests.conftest import warm_among_workers


def test_two_workers_warm_each_part_once_and_the_waiting_one_takes_the_extra(tmp_path):
    ran: list[str] = []
    lock = threading.Lock()

    def part(name: str, seconds: float):
        def warm() -> None:
            with lock:
                ran.append(name)
            time.sleep(seconds)

        return warm

    parts = (("slow", (), part("slow", 0.5)), ("after", ("slow",), part("after", 0.05)))
    extra = (("extra", (), part("extra", 0.1)),)
    returned: dict[int, set[str]] = {}

    def worker(i: int) -> None:
        warm_among_workers(parts, tmp_path, i, poll=0.01, extra=extra)
        returned[i] = {p.stem for p in tmp_path.glob("*.done")}

    threads = [threading.Thread(target=worker, args=(i,)) for i in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert sorted(ran) == ["after", "extra", "slow"]  # each once, and the extra by whoever waited on "slow"
    assert ran.index("slow") < ran.index("after")  # what a part needs comes first
    for i in (0, 1):
        assert {"slow", "after"} <= returned[i]  # no worker goes on before every part is done
