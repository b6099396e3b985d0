"""The engine's task-progress hub: nothing without a listener, every task's calls in order from
any thread, throttled advances, a failing listener dropped."""

import threading

import pytest

from spectralize.engine import progress
from spectralize.schemas import ParameterError


class Recorder:
    def __init__(self):
        self.calls = []
        self.lock = threading.Lock()

    def task_started(self, key, label, total):
        with self.lock:
            self.calls.append(("started", key, label, total))

    def task_advanced(self, key, done, estimate=None):
        with self.lock:
            self.calls.append(("advanced", key, done))
            self.estimates = [*getattr(self, "estimates", []), estimate]

    def task_finished(self, key, done):
        with self.lock:
            self.calls.append(("finished", key, done))


def test_without_a_listener_a_task_is_none_and_nothing_is_told():
    assert not progress.listened()
    with progress.task("images 1, 2", total=10) as task:
        assert task is None


def test_a_task_tells_its_start_progress_and_end():
    recorder = Recorder()
    with progress.listening(recorder):
        assert progress.listened()
        with progress.task("images 1, 2", total=10, interval=0.0) as task:
            for done in (1, 2, 3):
                task.advance(done)
    assert not progress.listened()
    key = task.key
    assert recorder.calls == [
        ("started", key, "images 1, 2", 10),
        ("advanced", key, 1),
        ("advanced", key, 2),
        ("advanced", key, 3),
        ("finished", key, 3),
    ]
    with progress.task("after", total=1) as after:  # the listener is gone
        assert after is None
    assert len(recorder.calls) == 5


def test_advances_are_throttled_but_the_end_carries_the_last_count():
    recorder = Recorder()
    with progress.listening(recorder), progress.task("set", total=1000, interval=3600.0) as task:
        for done in range(1, 1001):
            task.advance(done)
    assert [c[0] for c in recorder.calls] == ["started", "advanced", "finished"]
    assert recorder.calls[1][2] == 1  # the first advance is told at once
    assert recorder.calls[2][2] == 1000


def test_the_end_is_told_when_the_task_fails():
    recorder = Recorder()
    with progress.listening(recorder), pytest.raises(RuntimeError, match="solver broke"):
        with progress.task("set", total=5, interval=0.0) as task:
            task.advance(2)
            raise RuntimeError("solver broke")
    assert recorder.calls[-1] == ("finished", task.key, 2)


def test_tasks_in_worker_threads_reach_a_listener_registered_elsewhere():
    # dask's worker threads do not carry the registering thread's contextvars
    recorder = Recorder()

    def solve(index):
        with progress.task(f"set {index}", total=3, interval=0.0) as task:
            for done in range(1, 4):
                task.advance(done)

    with progress.listening(recorder):
        threads = [threading.Thread(target=solve, args=(i,)) for i in range(4)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    keys = {c[1] for c in recorder.calls}
    assert len(keys) == 4  # every task has its own key
    for key in keys:
        own = [c for c in recorder.calls if c[1] == key]
        assert [c[0] for c in own] == ["started", "advanced", "advanced", "advanced", "finished"]
        assert [c[2] for c in own[1:]] == [1, 2, 3, 3]
    assert {c[2] for c in recorder.calls if c[0] == "started"} == {f"set {i}" for i in range(4)}


def test_a_failing_listener_is_dropped_and_the_task_goes_on(capsys):
    class Broken(Recorder):
        def task_advanced(self, key, done, estimate=None):
            raise ValueError("display broke")

    broken, healthy = Broken(), Recorder()
    with progress.listening(broken), progress.listening(healthy):
        with progress.task("set", total=3, interval=0.0) as task:
            task.advance(1)
            task.advance(2)
    assert (
        capsys.readouterr().err.count("task progress listener stopped: ValueError: display broke") == 1
    )
    assert [c[0] for c in broken.calls] == ["started"]  # nothing after its failure
    assert [c[0] for c in healthy.calls] == ["started", "advanced", "advanced", "finished"]


@pytest.mark.parametrize("total, interval", [(-1, 0.1), (5, -1.0)])
def test_invalid_totals_and_intervals_are_refused(total, interval):
    with pytest.raises(ParameterError, match="task 'set'") as raised:
        with progress.task("set", total=total, interval=interval):
            pass
    assert isinstance(raised.value, ValueError)
    (problem,) = raised.value.problems
    wrong = ("total", -1) if total < 0 else ("interval", -1.0)
    assert problem.where == f"task 'set' {wrong[0]}" and problem.found == repr(wrong[1])


def test_a_task_tells_the_images_it_completes_to_the_listeners_that_count_them():
    """``images=``: told right after the start to a listener with ``task_images``; a listener
    without the method hears the same start and end, and a negative count is refused."""

    class Counting(Recorder):
        def task_images(self, key, images):
            with self.lock:
                self.calls.append(("images", key, images))

    counting, older = Counting(), Recorder()
    with progress.listening(counting), progress.listening(older):
        with progress.task("images 4, 5", total=3, images=2) as task:
            task.advance(3)
    key = task.key
    assert counting.calls[:2] == [("started", key, "images 4, 5", 3), ("images", key, 2.0)]
    assert [c[0] for c in older.calls] == ["started", "advanced", "finished"]
    for wrong in (-1.0, float("nan")):
        with pytest.raises(ParameterError, match="task 'set' images"):
            with progress.task("set", images=wrong):
                pass


def test_the_convergence_estimate_reads_the_rate_off_the_residuals():
    # r_k = 0.5^k: log(2^-20 / 2^-30) / log 2 = 10 iterations left, plus 5 fixed ones
    residuals = [(k, 0.5**k) for k in range(1, 21)]
    done, left = progress.convergence_estimate(residuals, 2.0**-30, fixed=5)
    assert done == 20 and left == pytest.approx(15.0)
    assert progress.convergence_estimate(residuals[:1], 1e-9) is None  # no rate yet
    assert progress.convergence_estimate([(20, 0.1), (21, 0.2)], 1e-9) is None  # no decrease
    assert progress.convergence_estimate([(20, 0.1), (21, 1e-10)], 1e-9) == (21.0, 0.0)


def test_a_solver_task_is_estimated_from_its_convergence_not_its_limit(monkeypatch):
    now = [0.0]
    monkeypatch.setattr(progress.time, "monotonic", lambda: now[0])
    recorder = Recorder()
    with progress.listening(recorder):
        with progress.task("set", total=1000, tolerance=2.0**-30, interval=0.0) as task:
            for k in range(1, 21):  # 2 s per iteration, residual halves each time
                now[0] = 2.0 * k
                task.advance(k, 0.5**k)
    fraction, seconds = recorder.estimates[-1]
    # 10 iterations left at 2 s each (measured since the first), not 980 of the limit; the
    # share done in time: 40 s spent of 60 s
    assert seconds == pytest.approx(20.0) and fraction == pytest.approx(2 / 3)
    assert recorder.estimates[0] is None  # one report: no rate yet
    assert recorder.estimates[18] is None  # 19 iterations: not trusted yet
