"""Progress display: the store's region messages drive it, solver runs report their iterations
under their node, plain lines carry an ETA, the rich bars render, and Prefect's console is quiet
unless verbose."""

import io
import logging
import sys
import threading
import time

import dask
import dask.array as da
import numpy as np
import pytest
import xarray as xr

from spectralize.engine import progress as engine_progress
from spectralize.engine.progress import Estimate
from spectralize.flows import progress
from spectralize.flows.progress import (
    Counted,
    PlainProgress,
    RichProgress,
    SetClock,
    format_seconds,
    listening,
    node_tasks,
    quiet_prefect,
    store_message,
)
from spectralize.nodes.reconstruction.tiling import solve_set, solve_tiled
from spectralize.store import RunStore


class Recorder:
    def __init__(self):
        self.calls = []

    def step_started(self, *args):
        self.calls.append(("step_started", *args))

    def stage(self, *args):
        self.calls.append(("stage", *args))

    def regions(self, *args):
        self.calls.append(("regions", *args))

    def step_finished(self, *args):
        self.calls.append(("step_finished", *args))


def lazy_cube(fail_at=None):
    def block(i):
        if i == fail_at:
            raise RuntimeError(f"crash in region {i}")
        return np.full((1, 4, 4), i, np.float32)

    pieces = [da.from_delayed(dask.delayed(block)(i), (1, 4, 4), np.float32) for i in range(4)]
    return xr.Dataset({"v": (("image", "y", "x"), da.concatenate(pieces), {"units": "1"})})


def test_the_store_region_messages_drive_the_display_also_when_resuming(tmp_path):
    store = RunStore.create(tmp_path / "run.zarr")
    recorder = Recorder()

    def write(ds):
        resumed = {}
        store.write(
            "cube",
            ds,
            fingerprint="fp",
            resumable_along="image",
            progress=lambda message: store_message("node", "cube", message, resumed),
        )

    with listening(recorder):
        with pytest.raises(RuntimeError, match="region 2"):
            write(lazy_cube(fail_at=2))
        assert recorder.calls == [
            ("regions", "node", "cube", 1, 4, 0, Counted(1, 4, 0, "image")),
            ("regions", "node", "cube", 2, 4, 0, Counted(2, 4, 0, "image")),
        ]
        recorder.calls.clear()
        write(lazy_cube())
    assert recorder.calls == [
        ("regions", "node", "cube", 2, 4, 2, Counted(2, 4, 2, "image")),  # by the failed run
        ("regions", "node", "cube", 3, 4, 2, Counted(3, 4, 2, "image")),
        ("regions", "node", "cube", 4, 4, 2, Counted(4, 4, 2, "image")),
    ]
    progress.notify("regions", "node", "cube", 4, 4, 0)  # no listener left: nothing happens
    assert len(recorder.calls) == 3


def test_the_store_messages_count_along_the_dim_when_a_region_is_a_batch(tmp_path):
    """Regions of 1, 3 and 2 images (batches of sets): the count is of images, not regions."""
    store = RunStore.create(tmp_path / "run.zarr")
    recorder = Recorder()
    pieces = [
        da.from_delayed(dask.delayed(np.full)((n, 4, 4), i, np.float32), (n, 4, 4), np.float32)
        for i, n in enumerate((1, 3, 2))
    ]
    cube = xr.Dataset({"v": (("image", "y", "x"), da.concatenate(pieces), {"units": "1"})})
    resumed = {}
    with listening(recorder):
        store.write(
            "cube",
            cube,
            fingerprint="fp",
            resumable_along="image",
            concurrent_regions=1,
            progress=lambda message: store_message("node", "cube", message, resumed),
        )
    assert [call[6] for call in recorder.calls] == [
        Counted(1, 6, 0, "image"),
        Counted(4, 6, 0, "image"),
        Counted(6, 6, 0, "image"),
    ]
    assert Counted(4, 6, 0, "image").text() == "4/6 images"
    assert Counted(2390, 5280, 0, "image").text() == "2,390/5,280 images"
    assert Counted(1, 1, 0, "image").text() == "1/1 image"


def test_plain_lines_say_the_node_the_image_sets_and_the_time_left():
    now = [100.0]
    out = io.StringIO()
    display = PlainProgress(out, clock=lambda: now[0])
    display.step_started(10, 12, "reconstruct_image_sets")
    display.stage("reconstruct_image_sets", "computing and writing spectra")
    # sets of 3 images (resumed), 2 and 3: the store's count along the dim names the images
    display.regions("reconstruct_image_sets", "spectra", 3, 10, 3, Counted(9, 30, 9, "image"))
    now[0] = 130.0
    display.regions("reconstruct_image_sets", "spectra", 4, 10, 3, Counted(11, 30, 9, "image"))
    now[0] = 160.0
    display.regions("reconstruct_image_sets", "spectra", 5, 10, 3, Counted(14, 30, 9, "image"))
    now[0] = 170.0
    display.regions("reconstruct_image_sets", "spectra", 6, 10, 3)  # no count: 70 s per 3 sets
    display.step_finished("reconstruct_image_sets", "ran", 75.0)
    assert out.getvalue().splitlines() == [  # 30 s per set: 5 left after the 5th
        "[10/12] reconstruct_image_sets",
        "    reconstruct_image_sets: computing and writing spectra",
        (
            "    reconstruct_image_sets: spectra: 9/30 images written by an earlier run "
            "(3/10 region(s)), resuming"
        ),
        "    reconstruct_image_sets: spectra: 11/30 images written, about 3 min 00 s left",
        "    reconstruct_image_sets: spectra: 14/30 images written, about 2 min 30 s left",
        "    reconstruct_image_sets: spectra: 6/10 region(s) written, about 1 min 33 s left",
        "    reconstruct_image_sets: done in 1 min 15 s",
    ]


def test_format_seconds():
    assert [format_seconds(s) for s in (4.4, 65, 7300)] == ["4 s", "1 min 05 s", "2 h 01 min"]


def test_the_rich_bar_renders_on_a_terminal():
    from rich.console import Console

    out = io.StringIO()
    with RichProgress(Console(file=out, force_terminal=True, width=140)) as display:
        with listening(display):
            progress.notify("step_started", 1, 2, "reconstruct_image_sets")
            progress.notify("stage", "reconstruct_image_sets", "computing and writing spectra")
            for done in range(1, 5):
                progress.notify("regions", "reconstruct_image_sets", "spectra", done, 4, 0)
                display.progress.refresh()
            text = out.getvalue()
            progress.notify("step_finished", "reconstruct_image_sets", "ran", 3.0)
    assert "spectra" in text and "4/4 region(s) written" in text
    assert "[1/2] reconstruct_image_sets: done in 3 s" in out.getvalue()


def test_a_failing_display_is_dropped_not_the_run(capsys):
    class Broken(Recorder):
        def stage(self, *args):
            raise ValueError("boom")

    broken = Broken()
    with listening(broken):
        progress.notify("stage", "node", "computing")
        progress.notify("stage", "node", "computing")  # dropped after the first error
        progress.notify("step_finished", "node", "ran", 1.0)
    assert capsys.readouterr().err.count("progress display stopped: ValueError: boom") == 1
    assert broken.calls == []


def test_prefect_console_is_quiet_unless_verbose(monkeypatch):
    monkeypatch.delenv(progress._CONSOLE_LEVEL, raising=False)
    quiet_prefect(verbose=False)
    assert progress.os.environ[progress._CONSOLE_LEVEL] == "WARNING"
    if "prefect" in sys.modules:  # already configured in this process: its handlers follow
        handlers = [
            h for h in logging.getLogger().handlers if type(h).__name__ == "PrefectConsoleHandler"
        ]
        assert all(h.level == logging.WARNING for h in handlers)
    quiet_prefect(verbose=True)
    assert progress.os.environ[progress._CONSOLE_LEVEL] == "INFO"


# -- solver runs inside a node (spectralize.engine.progress -> node_tasks -> the displays) ----


class TaskRecorder(Recorder):
    def task_started(self, *args):
        self.calls.append(("task_started", *args))
        self.thread = threading.current_thread()

    def task_advanced(self, *args):
        self.calls.append(("task_advanced", *args))

    def task_finished(self, *args):
        self.calls.append(("task_finished", *args))


def small_set(size=12, n_wavelength=6):
    """A two-image set: HDR RGB, band shots of image 10 and the camera matrix, from smooth
    spectra (a real, small eq. 1)."""
    rng = np.random.default_rng(3)
    wavelength = np.linspace(450.0, 650.0, n_wavelength)
    centres = np.array([600.0, 540.0, 460.0])
    c = np.exp(-0.5 * ((wavelength[None, :] - centres[:, None]) / 40.0) ** 2)
    y, x = np.mgrid[0:size, 0:size] / size
    truth = np.stack(
        [
            0.3
            + 0.2 * np.cos(3 * y + 2 * x + m)[None] * np.linspace(0.5, 1.0, n_wavelength)[:, None, None]
            for m in range(2)
        ]
    )  # (image, wavelength, y, x)
    rgb = xr.DataArray(
        np.einsum("cw,mwyx->myxc", c, truth),
        dims=("image", "y", "x", "channel"),
        coords={"image": [10, 11], "channel": ["R", "G", "B"]},
    )
    shots = xr.DataArray(
        truth[0] + 0.01 * rng.normal(size=truth[0].shape),
        dims=("shot", "y", "x"),
        coords={
            "wavelength": ("shot", wavelength),
            "image": ("shot", np.full(n_wavelength, 10)),
            "filter_size": ("shot", np.full(n_wavelength, 3.0)),
        },
    )
    camera = xr.DataArray(
        c, dims=("channel", "wavelength"), coords={"channel": ["R", "G", "B"], "wavelength": wavelength}
    )
    return rgb, shots, camera


def _refinement() -> int:
    """The default method's projected-gradient iterations on ``S >= 0`` after its CG."""
    from spectralize.nodes.reconstruction import DEFAULT_METHOD, RECONSTRUCTION_METHODS

    return int(RECONSTRUCTION_METHODS[DEFAULT_METHOD].defaults()["projected_iterations"])


def test_a_real_solve_reports_its_iterations_under_its_node_also_from_a_dask_thread():
    rgb, shots, camera = small_set()
    recorder = TaskRecorder()
    solve = dask.delayed(solve_set)(rgb, shots, camera, tolerance=1e-9, max_iterations=40)
    with listening(recorder), node_tasks("reconstruct_seed_set"):
        spectra, iterations, _ = solve.compute(scheduler="threads")  # in a worker thread
    refinement = _refinement()  # the default's S >= 0 iterations after at most 40 of CG
    assert refinement == 10
    assert spectra.sizes["image"] == 2 and 1 + refinement <= iterations <= 40 + refinement
    assert recorder.thread is not threading.main_thread()
    assert [c[0] for c in recorder.calls][:2] == ["task_started", "task_advanced"]
    started, *advanced, finished = recorder.calls
    key = started[2]
    assert started == ("task_started", "reconstruct_seed_set", key, "images 11", 40 + refinement)
    assert all(c[:3] == ("task_advanced", "reconstruct_seed_set", key) for c in advanced)
    assert advanced[0][3] == 1  # the first iteration is told at once, later ones throttled
    assert [c[3] for c in advanced] == sorted(c[3] for c in advanced)
    assert finished == ("task_finished", "reconstruct_seed_set", key, iterations)
    assert not engine_progress.listened()  # node_tasks unregistered its forwarder


def test_the_tiles_of_a_set_have_their_own_labels():
    rgb, shots, camera = small_set(size=16)
    recorder = TaskRecorder()
    with listening(recorder), node_tasks("reconstruct_seed_set"):
        solve_tiled(rgb, shots, camera, tile=8, halo=2, tolerance=1e-6, max_iterations=20)
    labels = [c[3] for c in recorder.calls if c[0] == "task_started"]
    expected = [f"images 11, tile y {y}:{y + 8}, x {x}:{x + 8}" for y in (0, 8) for x in (0, 8)]
    assert sorted(labels) == expected  # one bar per tile, in the order dask runs them
    assert len({c[2] for c in recorder.calls if c[0] == "task_started"}) == 4  # four bars


def test_without_a_display_nothing_listens_to_the_node_and_a_solve_still_runs():
    rgb, shots, camera = small_set()
    with node_tasks("reconstruct_seed_set"):  # nobody listens to the flow: nothing registered
        assert not engine_progress.listened()
        spectra, iterations, _ = solve_set(rgb, shots, camera, tolerance=1e-9, max_iterations=40)
    assert spectra.sizes["image"] == 2 and iterations >= 1


def test_a_display_without_the_task_methods_is_not_told_and_not_dropped(capsys):
    rgb, shots, camera = small_set()
    older = Recorder()  # step and region methods only
    with listening(older), node_tasks("reconstruct_seed_set"):
        solve_set(rgb, shots, camera, max_iterations=5)
        progress.notify("stage", "reconstruct_seed_set", "writing")
    assert older.calls == [("stage", "reconstruct_seed_set", "writing")]
    assert "progress display stopped" not in capsys.readouterr().err


def test_plain_solver_lines_at_most_every_ten_seconds_with_the_measured_time_left():
    now = [0.0]
    out = io.StringIO()
    display = PlainProgress(out, clock=lambda: now[0])
    display.task_started("reconstruct_image_sets", 7, "images 4, 5, 6", 400)
    display.task_started("reconstruct_image_sets", 8, "images 7, 8", 400)
    for second, done in [(2.0, 10), (9.0, 45), (12.0, 60), (18.0, 90), (25.0, 125)]:
        now[0] = second
        estimate = Estimate(done / 150, (150 - done) / 5)  # the engine's, measured: 150 in all
        display.task_advanced("reconstruct_image_sets", 7, done, estimate)
    now[0] = 5.0
    display.task_finished("reconstruct_image_sets", 8, 30)  # short: never printed, no end line
    now[0] = 30.0
    display.task_finished("reconstruct_image_sets", 7, 150)
    assert out.getvalue().splitlines() == [
        "    reconstruct_image_sets: images 4, 5, 6: iteration 60 (40 % of its work), about 18 s left",
        "    reconstruct_image_sets: images 4, 5, 6: iteration 125 (83 % of its work), about 5 s left",
        "    reconstruct_image_sets: images 4, 5, 6: done after 150 iteration(s) in 30 s",
    ]


def test_a_real_solve_on_the_plain_display_prints_a_solver_line():
    rgb, shots, camera = small_set()
    clock = iter(range(0, 100_000, 20))  # 20 s pass between two looks at the clock
    out = io.StringIO()
    display = PlainProgress(out, clock=lambda: float(next(clock)))
    with listening(display), node_tasks("reconstruct_seed_set"):
        _, iterations, _ = solve_set(rgb, shots, camera, tolerance=1e-9, max_iterations=40)
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("    reconstruct_seed_set: images 11: iteration 1")
    assert "/40" not in out.getvalue()  # never the iteration limit
    assert lines[-1].startswith(
        f"    reconstruct_seed_set: images 11: done after {iterations} iteration(s)"
    )


def test_the_image_sets_clock_counts_the_work_of_running_sets():
    clock = SetClock()
    clock.regions("node", 0, 4, 0, now=0.0)
    clock.task_started("node", 1, now=0.0)
    clock.task_started("node", 2, now=0.0)
    assert clock.estimate("node", 10.0) == (0.0, None)  # nothing measured yet
    clock.task_advanced("node", 1, Estimate(0.5, 10.0))
    clock.task_advanced("node", 2, Estimate(0.5, 10.0))
    # one set's work in 10 s: three left, 30 s (two running at a time show as the rate)
    assert clock.estimate("node", 10.0) == (1.0, 30.0)
    clock.task_finished("node", 1, now=20.0)  # solved in 20 s ...
    clock.regions("node", 1, 4, 0, now=25.0)  # ... and written 5 s later: a set is 25 s
    clock.task_advanced("node", 2, Estimate(25 / 30, 5.0))  # its solve: 30 s, then 5 s more
    work, left = clock.estimate("node", 25.0)
    assert work == pytest.approx(1 + 25 / 35) and left == pytest.approx(25 / work * (4 - work))
    # a set without its solver's estimate yet: its time over a mean set's (20 s + 5 s)
    clock.task_started("node", 3, now=25.0)
    work_later, _ = clock.estimate("node", 30.0)
    # set 2 at its last estimate: 30 s spent of a 36 s solve and 5 s after it
    assert work_later == pytest.approx(1 + 30 / 41 + 5 / 25)


def test_the_image_sets_clock_counts_the_last_set_whole_though_workers_are_idle():
    clock = SetClock()
    clock.regions("node", 0, 3, 0, now=0.0)
    for key in (1, 2):  # two sets at a time, 10 s each, written as they are solved
        clock.task_started("node", key, now=0.0)
    for key in (1, 2):
        clock.task_finished("node", key, now=10.0)
    clock.regions("node", 2, 3, 0, now=10.0)
    clock.task_started("node", 3, now=10.0)
    # by the rate (two sets per 10 s) the last set would take ~5 s; run whole, 9.5 s are left;
    # alone it runs faster than beside another, by up to 2x: the geometric mean of the two
    work, left = clock.estimate("node", 10.5)
    by_rate = 10.5 / 2.05 * 0.95
    assert work == pytest.approx(2.05) and left == pytest.approx((by_rate * 9.5) ** 0.5)
    # its solver: a quarter done in 0.5 s, so 1.5 s left; the rate's 3.5 s, now the larger, stands
    clock.task_advanced("node", 3, Estimate(0.25, 1.5))
    assert clock.estimate("node", 10.5)[1] == pytest.approx(10.5 / 2.25 * 0.75)


def test_the_rich_display_shows_a_bar_per_running_solver():
    from rich.console import Console

    out = io.StringIO()
    with RichProgress(Console(file=out, force_terminal=True, width=120)) as display:
        with listening(display):
            progress.notify("step_started", 1, 2, "reconstruct_image_sets")
            progress.notify("task_started", "reconstruct_image_sets", 1, "images 4, 5, 6", 400)
            progress.notify("task_started", "reconstruct_image_sets", 2, "images 7, 8", 400)
            for done in (5, 10, 15):
                progress.notify(
                    "task_advanced", "reconstruct_image_sets", 1, done, Estimate(done / 20, 20 - done)
                )
                progress.notify("task_advanced", "reconstruct_image_sets", 2, done // 2, None)
                display.progress.refresh()
            running = out.getvalue()
            progress.notify("task_finished", "reconstruct_image_sets", 1, 20)
            assert len(display.progress.tasks) == 2  # the node and the other solver
            progress.notify("step_finished", "reconstruct_image_sets", "ran", 3.0)
            assert display.progress.tasks == []  # the node took its solver bars with it
    assert "images 4, 5, 6" in running and "iteration 15" in running
    assert "ETA 5 s" in running  # measured: 15 of 20 iterations' work, 1 s each
    assert "images 7, 8" in running and "iteration 7" in running and "ETA …" in running
    assert "/400" not in running and "<=" not in running  # never the iteration limit


# -- honest ETAs: measured against the time the work really took ---------------------------


def within_twice(estimates, start, end):
    """The ``(time, seconds left)`` estimates made between a quarter of the work's time and
    its last tenth (where one set more or less is most of what is left) that are not within
    2x of the time really left, as ``(estimate, real)`` pairs."""
    span = end - start
    return [
        (round(left, 2), round(end - when, 2))
        for when, left in estimates
        if start + 0.25 * span <= when <= end - 0.1 * span and not 0.5 <= left / (end - when) <= 2.0
    ]


@pytest.mark.slow
@pytest.mark.timing
def test_a_real_solves_eta_is_within_twice_the_time_it_really_took():
    solve_set(*small_set(size=12, n_wavelength=16), tolerance=1e-6)  # compiled before the clock
    # a set whose solve lasts over a second on a fast machine: five estimates or more
    rgb, shots, camera = small_set(size=160, n_wavelength=16)
    seen = []

    class Watch:
        def task_advanced(self, node, key, done, estimate):
            if estimate is not None:
                seen.append((time.monotonic(), estimate.seconds_left, done))

    with listening(Watch()), node_tasks("reconstruct_seed_set"):
        start = time.monotonic()
        _, iterations, _ = solve_set(rgb, shots, camera, tolerance=1e-6)
        end = time.monotonic()
    limit = 2000  # the preset's limit: the old display's "at most" estimate
    assert iterations < limit / 10 and len(seen) >= 5
    # from a quarter of the solve on (its set-up included), the estimates within 2x
    assert within_twice([s[:2] for s in seen], start, end) == []


@pytest.mark.slow
@pytest.mark.timing
def test_the_image_sets_eta_of_a_flow_run_is_within_twice_the_time_really_left(tmp_path):
    from spectralize.flows.pipelines import get_flow, step_parameters
    from spectralize.flows.runtime import run_steps

    node = "reconstruct_image_sets"
    estimates, started, finished = [], [], []

    class Watch(PlainProgress):
        """The plain display, recording the image sets' estimate at every event."""

        def _look(self, name):
            if name == node:
                work, left = self.sets.estimate(node, self.clock())
                if left is not None:
                    estimates.append((self.clock(), left))

        def regions(self, name, *args):
            super().regions(name, *args)
            self._look(name)

        def task_advanced(self, name, *args):
            super().task_advanced(name, *args)
            self._look(name)

        def step_started(self, index, total, name):
            if name == node:
                started.append(self.clock())
            super().step_started(index, total, name)

        def step_finished(self, name, status, seconds):
            if name == node:
                finished.append(self.clock())
            super().step_finished(name, status, seconds)

    # the demo flow's steps up to the image sets, as one flow run (its evaluation and report
    # come after the step watched and only lengthen this pass, which runs alone)
    steps = get_flow("demo").steps
    steps = steps[: [step.node for step in steps].index(node) + 1]
    parameters = {
        "simulate.recipe": "tiny",
        "simulate.size": 128,
        "select_image_sets.others_per_set": 2,
    }
    display = Watch(io.StringIO())
    with listening(display):
        run_steps(tmp_path / "run.zarr", step_parameters(steps, parameters), flow_name="demo")
    lines = display.stream.getvalue()
    assert "images written, about" in lines
    (start,), (end,) = started, finished
    assert len(estimates) >= 5
    assert within_twice(estimates, start, end) == []


# -- regions of many solver runs: a batch of image sets in one task (a full run) --------------


def replay_batches(display, regions=23, per_region=11, lanes=1, region_images=240, images=False):
    """Drive ``display`` (the real class, its clock injected) through a write of ``regions``
    regions, each one task solving ``per_region`` sets one after the other (a solver run of
    ``18 * lanes / per_region`` s each, so a region is written every 18 s), ``lanes`` tasks at
    a time as the store computes them; the store's messages in their order; with ``images``
    each solver run tells its images (``region_images / per_region``), as the node's do.
    Returns ``(time, seconds left at that time)`` per region written, from the display's
    SetClock."""
    node, now, key = "reconstruct_image_sets", [0.0], 0
    display.clock = lambda: now[0]
    solve = 18.0 * lanes / per_region
    events = []  # (time, order, call)
    free = [0.0] * lanes
    for _ in range(regions):
        lane = min(range(lanes), key=free.__getitem__)
        t = free[lane]
        for _ in range(per_region):
            key += 1
            events.append((t, 0, ("task_started", node, key, f"set {key}", 40)))
            if images:
                events.append((t, 0, ("task_images", node, key, region_images / per_region)))
            for share in (0.4, 0.8):  # the engine's estimates of the tiny solves: ~0 s left
                estimate = Estimate(share, (1 - share) * solve)
                events.append((t + share * solve, 1, ("task_advanced", node, key, 20, estimate)))
            t += solve
            events.append((t, 2, ("task_finished", node, key, 30)))
        events.append((t, 3, ("region",)))
        free[lane] = t
    left, written = [], 0
    for when, _, call in sorted(events, key=lambda e: e[:2]):
        now[0] = when
        if call[0] == "region":
            written += 1
            counted = Counted(written * region_images, regions * region_images, 0, "image")
            display.regions(node, "spectra", written, regions, 0, counted)
            left.append((when, display.sets.estimate(node, when)[1]))
        else:
            getattr(display, call[0])(*call[1:])
    return left


def test_the_eta_of_regions_of_many_solver_runs_is_the_time_per_region_so_far():
    """A full run's 23 regions, each a batch of 11 sets, one every 18 s: after 2 the time left
    is 21 x 18 s (each tiny solve's own estimate, ~0 s left, must not stand for the region's)."""
    out = io.StringIO()
    left = replay_batches(PlainProgress(out))
    assert left[1] == (pytest.approx(36.0), pytest.approx(21 * 18.0))
    assert [seconds for _, seconds in left[1:-1]] == pytest.approx(
        [(23 - n) * 18.0 for n in range(2, 23)]
    )
    lines = out.getvalue().splitlines()
    assert "spectra: 480/5,520 images written, about 6 min 18 s left" in lines[1]
    assert not any("about 0 s left" in line for line in lines[:-2])


def test_the_eta_of_batches_computed_two_at_a_time_is_the_time_per_region_so_far():
    """Two batches at a time (the store's write_regions on two cores), started together: they
    are written in pairs every 36 s. After a pair the time left is the regions left x 18 s;
    after the first of a pair (its partner not counted yet) at most (k + 1) / k times that."""
    left = replay_batches(PlainProgress(io.StringIO()), lanes=2)
    assert [when for when, _ in left[:4]] == pytest.approx([36.0, 36.0, 72.0, 72.0])
    assert left[1][1] == pytest.approx(21 * 18.0)  # after 2 of 23
    ratios = [seconds / ((23 - k) * 18.0) for k, (_, seconds) in enumerate(left[:-1], start=1)]
    assert ratios[1::2] == pytest.approx([1.0] * 11)  # after each pair
    assert ratios[0::2] == pytest.approx([(k + 1) / k for k in range(1, 23, 2)])


def test_the_rich_display_shows_the_same_eta_and_count_for_batches():
    from rich.console import Console

    plain = replay_batches(PlainProgress(io.StringIO()))
    with RichProgress(Console(file=io.StringIO(), force_terminal=True, width=120)) as display:
        display.step_started(10, 11, "reconstruct_image_sets")
        given = []  # (bar, its eta) as the display updates its bars
        update = display.progress.update

        def watch(task_id, **fields):
            if "eta" in fields:
                given.append((task_id, fields["eta"]))
            update(task_id, **fields)

        display.progress.update = watch
        rich = replay_batches(display)
        (bar,) = [t for t in display.progress.tasks if t.description.strip() == "spectra"]
        assert bar.fields["count"] == "5,520/5,520 images written"
    assert rich == plain  # the same SetClock estimate
    seen = [eta for task_id, eta in given if task_id == bar.id]
    assert pytest.approx(21 * 18.0) in seen  # its bar's ETA after 2 of 23 regions
    assert min(eta for eta in seen[:-1] if eta is not None) > 1.0  # never "0 s" before the end


# -- images, not batches: the node's solver runs tell the images they complete ---------------


def test_a_batch_of_sets_and_a_sets_tiles_tell_the_images_they_complete():
    """A batch's set tells its owned images (image 11 of 10, 11), a set's four tiles a
    quarter of its two images each: what the display counts, image by image."""
    from spectralize.nodes.reconstruction.set_reconstruction import _solve_sets

    class Counting(TaskRecorder):
        def task_images(self, *args):
            self.calls.append(("task_images", *args))

    rgb, shots, camera = small_set(size=16)
    recorder = Counting()
    with listening(recorder), node_tasks("reconstruct_image_sets"):
        _solve_sets(
            rgb,
            shots,
            shots["image"].values,
            camera,
            [(np.array([10, 11]), np.array([False, True]))],
            method=None,
            illuminant=None,
            warm=None,
        )
        solve_tiled(rgb, shots, camera, tile=8, halo=2, tolerance=1e-6, max_iterations=20)
    told = [c[3] for c in recorder.calls if c[0] == "task_images"]
    assert told == [1.0, 0.5, 0.5, 0.5, 0.5]
    started = [c[2] for c in recorder.calls if c[0] == "task_started"]
    assert [c[2] for c in recorder.calls if c[0] == "task_images"] == started  # one per run


def test_the_count_and_eta_of_batches_move_set_by_set_where_the_sets_tell_their_images():
    """The full run's batches of 11 sets: between two regions written, each set solved adds
    its images to the work done (without them the count stands still for a whole batch),
    and two batches computed at a time give the time really left after either of a pair."""
    looks = []

    class Looking(PlainProgress):
        def task_finished(self, node, key, done):
            super().task_finished(node, key, done)
            looks.append(self.sets.estimate(node, self.clock())[0])

    replay_batches(Looking(io.StringIO()), images=True)
    second = looks[2 * 11 - 11 : 2 * 11 - 1]  # the second batch's sets, before it is written
    assert second == pytest.approx([240 + j * 240 / 11 for j in range(1, 11)])
    left = replay_batches(PlainProgress(io.StringIO()), lanes=2, images=True)
    assert [seconds for _, seconds in left[:-1]] == pytest.approx(
        [18.0 * (23 - 2 * ((k + 1) // 2)) for k in range(1, 23)]
    )


def test_the_rich_bar_counts_images_done_of_images_in_all():
    from rich.console import Console

    with RichProgress(Console(file=io.StringIO(), force_terminal=True, width=120)) as display:
        display.step_started(10, 11, "reconstruct_image_sets")
        completed = []
        update = display.progress.update

        def watch(task_id, **fields):
            if "completed" in fields and task_id == display._bars.get(
                ("reconstruct_image_sets", "spectra")
            ):
                completed.append(fields["completed"])
            update(task_id, **fields)

        display.progress.update = watch
        replay_batches(display, images=True)
        (bar,) = [t for t in display.progress.tasks if t.description.strip() == "spectra"]
        assert bar.total == 5520 and bar.completed == 5520
    moved = sorted(set(round(c, 6) for c in completed))
    assert len(moved) > 5 * 23  # set by set, not one step per batch
    assert completed == sorted(completed)
