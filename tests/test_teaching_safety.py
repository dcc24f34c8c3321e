"""Issue 65: what teaching and export leave on disk, where they write, and how they fail.

Every file a reader may see is written under a temporary name and renamed into place; readers skip
temporaries as pyarrow does (names starting with ``_`` or ``.``); dead temporaries are found and
removed without following a symbolic link; a dataset id cannot leave ``--out``; a failed export
leaves nothing behind; ``serve`` checks its folder at start and answers a write failure with its
reason (503, or 507 for a full disk) and goes on serving; pictures are drawn from the frames they
show, not from every frame of the attempt."""

import errno
import os
import shutil
import subprocess
import time
import tracemalloc
from pathlib import Path

import minari
import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.parquet as pq
import pytest
from _cluster_tools import GPL_DIST, free_ports, quiet_env, wait_for_port

from gpl_dist import atomic
from gpl_dist.app.teaching import Teacher, TeachingError, write_episode_log
from gpl_dist.cli import main

TASK = 263  # a multi-room test task


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    run = tmp_path_factory.mktemp("safety") / "run"
    assert main(["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--no-progress", "--run-dir", str(run),
                 "--set", "training.num_rounds=1", "--set", "env.max_train_tasks=4",
                 "--set", "training.num_epochs_per_round=1"]) == 0
    return run


@pytest.fixture(scope="module")
def teacher(run) -> Teacher:
    return Teacher(run)


def _taught_log(teacher: Teacher, log: Path) -> list[str]:
    """A log of two episodes, three attempts in all; returns the episode ids."""
    one = teacher.episode(TASK, seed=3, source="test")
    one.attempt()
    one.attempt("enter the grey room")
    two = teacher.episode(TASK + 1, seed=4, source="test")
    two.attempt()
    write_episode_log(one, log)
    write_episode_log(two, log)
    return [one.episode_id, two.episode_id]


def _files(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")} if folder.exists() else set()


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("gpl-dist: error:") and "\n" not in err, err
    return err


def test_temporaries_in_a_teaching_log_change_nothing_that_export_reads(teacher, tmp_path, monkeypatch, capsys):
    """A ``kill -9`` or a full disk left ``_tmp-<hex>-<episode>.parquet`` beside the logs: a complete
    one exported its episode twice, an empty one failed the export. pyarrow.dataset skips them; so
    does the export."""
    log = tmp_path / "log"
    one, two = _taught_log(teacher, log)
    shutil.copy(log / f"{one}.parquet", log / f"_tmp-0123456789ab-{one}.parquet")  # complete, never renamed
    shutil.copy(log / f"{two}.parquet", log / f".{two}.parquet")  # hidden: skipped too
    expected = pads.dataset(str(log), format="parquet").to_table().num_rows
    assert expected == 3
    out = tmp_path / "datasets"
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    assert main(["export", str(log), "--out", str(out), "--dataset-id", "gpl-dist/complete-tmp-v0"]) == 0
    assert minari.load_dataset("gpl-dist/complete-tmp-v0").total_episodes == 3
    (log / f"_tmp-ba9876543210-{two}.parquet").write_bytes(b"")  # empty: the write died at once
    (log / "_tmp-fedcba987654-x.parquet").write_bytes(b"PAR1\x00\x00")  # truncated
    assert pads.dataset(str(log), format="parquet").to_table().num_rows == expected
    assert main(["export", str(log), "--out", str(out), "--dataset-id", "gpl-dist/empty-tmp-v0"]) == 0
    for name in ("complete-tmp", "empty-tmp"):
        dataset = minari.load_dataset(f"gpl-dist/{name}-v0")
        assert dataset.total_episodes == 3
        metas = list(dataset.storage.get_episode_metadata(dataset.episode_indices))
        assert sorted((m["episode"], m["attempt_index"]) for m in metas) == sorted([(one, 0), (one, 1), (two, 0)])
    # a folder of temporaries alone is no teaching log
    only_tmp = tmp_path / "only-tmp"
    only_tmp.mkdir()
    shutil.copy(log / f"{one}.parquet", only_tmp / f"_tmp-0123456789ab-{one}.parquet")
    from gpl_dist.app.export import is_teaching_log

    assert is_teaching_log(log) and not is_teaching_log(only_tmp)


def test_a_symlinked_log_file_is_refused_not_followed(teacher, tmp_path, capsys):
    log, elsewhere = tmp_path / "log", tmp_path / "elsewhere"
    _taught_log(teacher, log)
    linked = teacher.episode(TASK, seed=9, source="test")
    linked.attempt()
    write_episode_log(linked, elsewhere)
    (log / f"{linked.episode_id}.parquet").symlink_to(elsewhere / f"{linked.episode_id}.parquet")
    out = tmp_path / "datasets"
    assert main(["export", str(log), "--out", str(out), "--dataset-id", "gpl-dist/linked-v0"]) == 2
    err = _one_line_error(capsys)
    assert "symbolic link" in err and f"{linked.episode_id}.parquet" in err
    assert not out.exists()


@pytest.mark.parametrize("dataset_id, why", [
    ("../../x-v0", "namespace/name-vN"),
    ("gpl-dist/../../../x-v0", "namespace/name-vN"),
    ("ABSOLUTE/x-v0", "namespace/name-vN"),
    ("gpl-dist//x-v0", "namespace/name-vN"),
    ("gpl-dist/x", "namespace/name-vN"),  # no version: minari cannot load it
    ("gpl-dist/x-v0\n", "namespace/name-vN"),
    ("linked/x-v0", "outside"),  # a namespace folder that is a symbolic link out of --out
])
def test_a_dataset_id_that_leaves_out_is_refused_before_anything_is_written(run, tmp_path, capsys, dataset_id, why):
    out, outside = tmp_path / "datasets", tmp_path / "outside"
    out.mkdir()
    outside.mkdir()
    (out / "linked").symlink_to(outside)
    dataset_id = dataset_id.replace("ABSOLUTE", str(outside))
    before = _files(tmp_path)
    assert main(["export", str(run), "--out", str(out), "--dataset-id", dataset_id]) == 2
    err = _one_line_error(capsys)
    assert why in err, err
    assert _files(tmp_path) == before  # nothing written, in --out or out of it
    assert main(["export", str(run), "--out", str(out), "--dataset-id", "gpl-dist/x-v0"]) == 0  # a good id is written
    assert (out / "gpl-dist" / "x-v0" / "data" / "metadata.json").is_file()


def test_a_failed_export_leaves_nothing_that_blocks_a_retry(teacher, tmp_path, monkeypatch, capsys):
    """An export that fails half way (here: a log whose attempt replays differently, as another
    checkpoint's would) leaves no partial dataset: the same command succeeds once the cause is gone."""
    log = tmp_path / "log"
    _taught_log(teacher, log)
    bad = teacher.episode(TASK + 2, seed=5, source="test")
    bad.attempt()
    write_episode_log(bad, log)
    path = log / f"{bad.episode_id}.parquet"
    table = pq.read_table(path)
    wrong = pa.array([c + 0.5 for c in table.column("completion").to_pylist()], pa.float64())
    pq.write_table(table.set_column(table.schema.get_field_index("completion"), "completion", wrong), path)
    out = tmp_path / "datasets"
    assert main(["export", str(log), "--out", str(out), "--dataset-id", "gpl-dist/retry-v0"]) == 2
    assert "replays to completion" in _one_line_error(capsys)
    assert not [p for p in _files(out) if not (out / p).is_dir()]  # no partial dataset, no temporary
    assert not (out / "gpl-dist" / "retry-v0").exists()
    path.unlink()
    assert main(["export", str(log), "--out", str(out), "--dataset-id", "gpl-dist/retry-v0"]) == 0
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(out))
    assert minari.load_dataset("gpl-dist/retry-v0").total_episodes == 3
    assert not [p for p in _files(out) if Path(p).name.startswith(".")]  # the temporary folder was renamed


def test_a_failed_log_write_removes_its_temporary_and_says_why_in_one_line(teacher, tmp_path):
    log = tmp_path / "log"
    episode = teacher.episode(TASK, seed=3, source="test")
    episode.attempt()
    (log / f"{episode.episode_id}.parquet").mkdir(parents=True)  # the log file's name is taken by a folder
    with pytest.raises(TeachingError) as raised:
        write_episode_log(episode, log)
    assert "\n" not in str(raised.value) and f"{episode.episode_id}.parquet" in str(raised.value)
    assert sorted(p.name for p in log.iterdir()) == [f"{episode.episode_id}.parquet"]  # no _tmp- left


def test_serve_and_teach_with_out_a_file_fail_at_start_in_one_line(run, tmp_path, capsys):
    a_file = tmp_path / "not-a-folder"
    a_file.write_text("x")
    port = free_ports(1)[0]
    try:  # before: it served, and failed every request with a bare HTTP 500
        done = subprocess.run([GPL_DIST, "serve", "--run-dir", str(run), "--port", str(port), "--out", str(a_file)],
                              env=quiet_env(), capture_output=True, text=True, timeout=120)
    except subprocess.TimeoutExpired:
        pytest.fail("gpl-dist serve --out FILE started serving")
    err = done.stderr.strip()
    assert done.returncode == 2 and err.startswith("gpl-dist: error:") and "\n" not in err, err
    assert str(a_file) in err
    assert main(["teach", "--run-dir", str(run), "--task", str(TASK), "--out", str(a_file)]) == 2
    assert str(a_file) in _one_line_error(capsys)
    assert a_file.read_text() == "x"


def test_a_write_failure_in_serve_answers_its_reason_and_serving_goes_on(teacher, tmp_path, monkeypatch):
    from fastapi.testclient import TestClient

    from gpl_dist.app.teach_web import create_app

    out = tmp_path / "out"
    client = TestClient(create_app(teacher, out), base_url="http://127.0.0.1")
    log = out / "log"
    a = client.post("/api/episodes", json={"task_id": TASK, "seed": 3}).json()
    taken = log / f"{a['episode_id']}.parquet"
    taken.unlink()
    taken.mkdir()  # the episode's log cannot be replaced: not a full disk (503)
    r = client.post(f"/api/episodes/{a['episode_id']}/attempts", json={"correction": "enter the grey room"})
    assert r.status_code == 503, r.text[:300]
    detail = r.json()["detail"]
    assert "\n" not in detail and "not saved" in detail and taken.name in detail, detail
    assert sorted(p.name for p in log.iterdir()) == [taken.name]  # its temporary removed
    taken.rmdir()
    again = client.post(f"/api/episodes/{a['episode_id']}/attempts", json={"correction": "enter the grey room"})
    assert again.status_code == 200 and len(again.json()["attempts"]) == 2  # the failed attempt was not kept
    assert pads.dataset(str(log), format="parquet").to_table().num_rows == 2

    written = []

    def full_disk(fd, data):
        # A full disk cannot be made here without root (no tmpfs to fill): the write itself fails
        # as it would on one, after part of the file is on disk.
        if written:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        written.append(len(data))
        return os.write(fd, bytes(data[: len(data) // 2]))

    monkeypatch.setattr(atomic, "_os_write", full_disk)
    r = client.post("/api/episodes", json={"task_id": TASK, "seed": 4})
    assert r.status_code == 507 and "No space left on device" in r.json()["detail"], r.text[:300]
    assert "\n" not in r.json()["detail"] and written
    assert not [p for p in log.iterdir() if p.name.startswith("_tmp-")]  # the half-written temporary removed
    monkeypatch.undo()
    assert client.get("/api/info").status_code == 200  # still serving
    b = client.post("/api/episodes", json={"task_id": TASK, "seed": 4})
    assert b.status_code == 200
    shutil.rmtree(log)
    log.write_text("not a folder")  # --out's log folder replaced by a file while serving
    r = client.post(f"/api/episodes/{b.json()['episode_id']}/attempts", json={"correction": "enter the grey room"})
    assert r.status_code == 503 and "not a folder" in r.json()["detail"], r.text[:300]


def test_the_page_shows_why_an_attempt_was_not_saved(run, tmp_path):
    """The real server and Debian's chromium: the page names the cause of a failed write, and the
    next attempt, once the cause is gone, goes through."""
    from playwright.sync_api import expect, sync_playwright

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "the browser test needs Debian's chromium (apt-get install chromium; .ci/run does)"
    port = free_ports(1)[0]
    server = subprocess.Popen([GPL_DIST, "serve", "--run-dir", str(run), "--port", str(port), "--out", str(tmp_path)],
                              env=quiet_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        wait_for_port(port, server, seconds=120)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, headless=True, args=["--no-sandbox"])
            page = browser.new_page()
            page.goto(f"http://127.0.0.1:{port}/")
            page.fill("#task", str(TASK))
            page.click("#new")
            expect(page.locator(".attempt")).to_have_count(1, timeout=60_000)
            (taken,) = (tmp_path / "log").glob("*.parquet")
            taken.unlink()
            taken.mkdir()
            page.fill("#correction", "enter the grey room")
            page.click("#send")
            expect(page.locator("#message")).to_contain_text("not saved", timeout=60_000)
            expect(page.locator("#message")).to_contain_text(taken.name)
            expect(page.locator(".attempt")).to_have_count(1)
            taken.rmdir()
            page.click("#send")
            expect(page.locator(".attempt")).to_have_count(2, timeout=60_000)
            browser.close()
        assert server.poll() is None  # serving throughout
    finally:
        server.terminate()
        server.wait(timeout=30)


def _age(path: Path, seconds: float) -> None:
    t = time.time() - seconds
    os.utime(path, (t, t), follow_symlinks=False)


def test_teaching_leftovers_removes_dead_temporaries_and_keeps_a_live_writers(teacher, tmp_path):
    from gpl_dist.app.teaching import LEFTOVER_AGE_S, teaching_leftovers, teaching_writer

    folder = tmp_path / "teaching"
    one, _ = _taught_log(teacher, folder / "log")
    (folder / "gifs").mkdir()
    kept = [folder / "log" / f"{one}.parquet", folder / "log" / "_SUCCESS", folder / "log" / ".keep",
            folder / "gifs" / "e-attempt0.gif", folder / "notes-_tmp-x.txt"]
    for p in kept[1:]:
        p.write_bytes(b"mine")
    fresh = [folder / "log" / f"_tmp-0123456789ab-{one}.parquet", folder / "gifs" / "_tmp-0123456789ab-e-attempt1.gif"]
    old = [folder / "log" / "_tmp-ba9876543210-x.parquet"]
    for p in fresh + old:
        p.write_bytes(b"half")
    for p in old:
        _age(p, LEFTOVER_AGE_S + 60)
    with teaching_writer(folder):  # a serve or teach writing into the folder now: only old temporaries are dead
        assert teaching_leftovers(folder, dry_run=True) == [str(p) for p in old]
        assert teaching_leftovers(folder, dry_run=False) == [str(p) for p in old]
        assert all(p.exists() for p in fresh + kept) and not any(p.exists() for p in old)
    # no writer left: every temporary is dead (a killed writer's lock went with it)
    expected = sorted(str(p) for p in fresh)
    assert teaching_leftovers(folder, dry_run=True) == expected and all(p.exists() for p in fresh)
    assert teaching_leftovers(folder, dry_run=False) == expected
    assert not any(p.exists() for p in fresh) and all(p.read_bytes() for p in kept)
    assert teaching_leftovers(folder, dry_run=False) == []
    assert teaching_leftovers(tmp_path / "nothing-here", dry_run=False) == []


@pytest.mark.parametrize("where", ["log", "entry", "folder"])
def test_teaching_leftovers_never_follows_a_symlink(tmp_path, where):
    from gpl_dist.app.teaching import teaching_leftovers

    outside = tmp_path / "outside"
    outside.mkdir()
    victim = outside / "_tmp-0123456789ab-victim.parquet"
    victim.write_bytes(b"not yours")
    folder = tmp_path / "teaching"
    folder.mkdir()
    dead = folder / "_tmp-ba9876543210-probe"
    dead.write_bytes(b"")
    if where == "log":
        (folder / "log").symlink_to(outside)
    elif where == "entry":
        (folder / "log").mkdir()
        (folder / "log" / "_tmp-fedcba987654-x.parquet").symlink_to(victim)
    else:
        folder = tmp_path / "linked"
        folder.symlink_to(tmp_path / "teaching")
    for dry_run in (True, False):
        with pytest.raises(TeachingError) as raised:
            teaching_leftovers(folder, dry_run=dry_run)
        assert "symbolic link" in str(raised.value) and "\n" not in str(raised.value)
    assert victim.read_bytes() == b"not yours" and dead.exists()  # refused before anything was removed


def test_pictures_are_drawn_from_the_frames_they_show(teacher):
    """``serve`` held about 40 MB an episode: each picture stepped the attempt again keeping every
    full-size frame (101 of 1.1 MB). The same pictures, byte for byte, from the frames they show."""
    from PIL import Image

    from gpl_dist.app.rendering import captioned_attempt_frames, gif_bytes, replay_attempt, still_frame
    from gpl_dist.app.teaching import STRIP_FRAME_PX, _png

    episode = teacher.episode(TASK, seed=3, source="test")
    a = episode.attempt()
    full = replay_attempt(teacher.domain.name, TASK, a.actions, a.reset_seed)
    frame_bytes = full.frames[0].nbytes
    top = f"attempt 1: instruction: {a.said_before}"
    expected_gif = gif_bytes(captioned_attempt_frames(teacher.domain.name, TASK, a.actions, a.reset_seed, top))
    shown = [Image.fromarray(full.frames[t]) for t in episode.strip_steps(0)]
    h = round(shown[0].height * STRIP_FRAME_PX / shown[0].width)
    strip = Image.new("RGB", (STRIP_FRAME_PX * len(shown), h), "white")
    for i, f in enumerate(shown):
        strip.paste(f.resize((STRIP_FRAME_PX, h)), (i * STRIP_FRAME_PX, 0))
    expected = {"gif": expected_gif, "strip": _png(strip), "still": _png(Image.fromarray(still_frame(full)))}
    del full, shown, strip
    for kind, draw in (("gif", episode.gif), ("strip", episode.film_strip), ("still", episode.still)):
        tracemalloc.start()
        try:
            got = draw(0)
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert got == expected[kind], kind
        assert peak < 20 * frame_bytes, (kind, peak / frame_bytes)  # before: more than the attempt's 101 frames
    assert len(a.actions) + 1 > 90
