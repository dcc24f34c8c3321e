"""Teaching a trained policy: the checker, the episode (seeded replay, as meta-test), the log, the
terminal loop, the web API, and a real browser through a full episode."""

import io
import json
import shutil
import socket
import subprocess
import time
from pathlib import Path

import numpy as np
import pyarrow.dataset as pads
import pytest
from _cluster_tools import GPL_DIST, free_ports, quiet_env, wait_for_port

from gpl_dist.app.teaching import (
    MAX_TEXT_CHARS,
    Teacher,
    TeachingError,
    check_correction,
    write_episode_log,
)
from gpl_dist.cli import main
from gpl_dist.domains import get_domain
from gpl_dist.language import split_words
from learner.evaluate import load_trained_policy, meta_test_rollout

TASK = 263  # a multi-room test task


def _train(run: Path, *sets: str) -> Path:
    args = ["train", "--config", "configs/multiroom-smoke.yaml", "--serial", "--no-progress", "--run-dir", str(run),
            "--set", "training.num_rounds=1", "--set", "env.max_train_tasks=4", "--set", "training.num_epochs_per_round=1"]
    for s in sets:
        args += ["--set", s]
    assert main(args) == 0
    return run


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    return _train(tmp_path_factory.mktemp("teach") / "run")


@pytest.fixture(scope="module")
def teacher(run) -> Teacher:
    return Teacher(run)


MULTIROOM = get_domain("multiroom")


@pytest.mark.parametrize("text, needle", [
    ("", "empty"),
    ("   \t ", "empty"),
    ("x" * 10_000, f"at most {MAX_TEXT_CHARS}"),
    ("enter the\x07 blue room", "control characters"),
    ("enter the\u200b blue room", "control characters"),
    ("Geh in den blauen Raum", "knows too few of the words"),
    ("进入蓝色房间", "no English words"),
    (" ".join(["enter the blue room"] * 9), "this policy reads at most 32"),
])
def test_unusable_corrections_are_refused_with_a_reason(text, needle):
    check = check_correction(MULTIROOM, text)
    assert not check.usable and needle in check.problem
    assert len(check.text) <= MAX_TEXT_CHARS + 1


def test_unknown_words_are_pointed_out_with_the_closest_known_phrasing():
    check = check_correction(MULTIROOM, "Enter the GRY room!")
    assert check.usable and check.unknown_words == ("gry",)
    assert check.suggestion == "enter the grey room"
    vocab = MULTIROOM.vocabulary
    assert check.token_ids == tuple(int(i) for i in vocab.encode("enter the <unk> room") if i)
    known = check_correction(MULTIROOM, "enter the grey room")
    assert known.usable and known.unknown_words == () and known.suggestion is None
    assert check_correction(get_domain("relocation"), "move a litle left").suggestion == "Move a little left"


def test_a_person_typing_the_oracles_corrections_gets_meta_tests_attempts(teacher, run):
    """The teaching loop is Algorithm 2 with a person in the oracle's place: typing what the oracle
    says reproduces the meta-test rollout's attempts action for action."""
    cfg, model, _ = load_trained_policy(run)
    model.eval()
    expected = meta_test_rollout(cfg, model).run([TASK], 2, 7, split="teach").attempts
    episode = teacher.episode(TASK, seed=7)
    got = [episode.attempt()]
    for k in range(1, len(expected)):
        got.append(episode.attempt(expected[k - 1].correction))
    assert len(expected) >= 2
    for a, b in zip(got, expected):
        assert np.array_equal(a.actions, b.actions) and a.completion == b.completion
    assert got[1].said_before == expected[0].correction


def test_episodes_replay_exactly_and_bad_input_changes_nothing(teacher):
    one, two = teacher.episode(TASK, seed=3), teacher.episode(TASK, seed=3)
    with pytest.raises(TeachingError, match="first attempt"):
        one.attempt("enter the blue room")  # a correction before any attempt
    first = one.attempt()
    assert np.array_equal(two.attempt().actions, first.actions)
    for bad in ("", "x" * 10_000, "a\x00b", "Geh nach Norden", None):
        with pytest.raises(TeachingError):
            one.attempt(bad)
        assert len(one.attempts) == 1  # refused input leaves the episode as it was
    with pytest.raises(TeachingError, match="no attempt"):
        teacher.episode(TASK, seed=3).hint()
    a = one.attempt("enter the blu room")  # an unknown word is sent as <unk>
    b = two.attempt("enter the blu room")
    assert a.check.unknown_words == ("blu",) and np.array_equal(a.actions, b.actions)
    assert len(two.attempts) == 2 and one.episode_id != two.episode_id


def test_the_hint_is_what_the_runs_oracle_says_after_the_attempt(teacher, run):
    cfg, model, _ = load_trained_policy(run)
    model.eval()
    expected = meta_test_rollout(cfg, model).run([TASK], 1, 11, split="teach").attempts
    episode = teacher.episode(TASK, seed=11)
    episode.attempt()
    if expected[0].success:
        pytest.fail("task solved on the first attempt: pick another task for this test")
    assert episode.hint() == expected[0].correction


@pytest.fixture(scope="module")
def paraphrased(tmp_path_factory) -> Teacher:
    """A run trained with the domain's training paraphrases (``model.paraphrases``)."""
    return Teacher(_train(tmp_path_factory.mktemp("teach-paraphrased") / "run", "model.paraphrases=true"))


def _said(texts) -> set[str]:
    return {" ".join(split_words(t)) for t in texts}


def test_a_run_trained_without_paraphrases_offers_none_and_warns_on_them(teacher, tmp_path):
    from fastapi.testclient import TestClient

    from gpl_dist.app.teach_web import create_app

    kind = teacher.cfg.env.correction_kind
    own = _said(MULTIROOM.phrasings_of(kind))
    only_paraphrases = _said(MULTIROOM.paraphrased(MULTIROOM.phrasings_of(kind), ("train", "heldout"))) - own
    assert not teacher.paraphrases and only_paraphrases
    examples = TestClient(create_app(teacher, tmp_path), base_url="http://127.0.0.1").get("/api/info").json()["examples"]
    assert examples == teacher.examples() and len(examples) == 6 and _said(examples) <= own
    assert not _said(teacher.phrasings) & only_paraphrases  # never suggested
    check = teacher.check("go into the blue room")  # a training paraphrase of "enter the blue room"
    assert check.usable and check.warning is not None and check.suggestion in MULTIROOM.phrasings_of(kind)
    assert teacher.check("enter the blue room").warning is None


def test_a_run_trained_with_paraphrases_offers_and_accepts_them(paraphrased, tmp_path):
    from fastapi.testclient import TestClient

    from gpl_dist.app.teach_web import create_app

    kind = paraphrased.cfg.env.correction_kind
    canonical = _said(MULTIROOM.phrasings_of(kind))
    trained = _said(MULTIROOM.phrasings_of(kind, paraphrases=True))
    examples = TestClient(create_app(paraphrased, tmp_path), base_url="http://127.0.0.1").get("/api/info").json()["examples"]
    assert examples == paraphrased.examples() and len(examples) == 6
    assert _said(examples) <= trained and _said(examples) - canonical and _said(examples) & canonical
    assert trained - canonical and _said(paraphrased.phrasings) == trained
    said = "go into the blue room"
    assert " ".join(split_words(said)) in trained - canonical
    check = paraphrased.check(said)  # a training paraphrase: known, no suggestion, no warning
    assert check.usable and check.unknown_words == () and check.suggestion is None and check.warning is None
    assert paraphrased.check("go into the blu room").suggestion == said  # the closest trained phrasing: a paraphrase
    heldout = _said(MULTIROOM.paraphrased(MULTIROOM.phrasings_of(kind), ("heldout",))) - trained
    assert heldout and paraphrased.check(sorted(heldout)[0]).warning is not None  # never trained on
    other = MULTIROOM.paraphrased(MULTIROOM.phrasings_of("directional"), ("train",))[1]  # another kind's paraphrase
    assert paraphrased.check(other).warning is not None
    episode = paraphrased.episode(TASK, seed=3)
    episode.attempt()
    sent = episode.attempt(said)
    assert sent.check is not None and sent.check.warning is None
    vocab = paraphrased.model.vocabulary
    assert sent.record.attempt_index == 1 and vocab.unk_id not in sent.check.token_ids
    hint = episode.hint()  # the oracle's sentence, of the run's kind: one it trained on
    assert " ".join(split_words(hint)) in trained


def test_tasks_are_chosen_by_id_instruction_or_draw(teacher):
    env = MULTIROOM.make_env(TASK)
    shouted = "  " + env.instruction.upper() + "!! "
    chosen = teacher.resolve_task(instruction=shouted, seed=0)
    assert split_words(MULTIROOM.make_env(chosen).instruction) == split_words(env.instruction)
    assert teacher.resolve_task(seed=5) == teacher.resolve_task(seed=5)
    for bad in (-1, MULTIROOM.num_tasks, 10**30, True):
        with pytest.raises(TeachingError, match="outside"):
            teacher.resolve_task(task_id=bad)
    for seed in (-1, 2**32, 2**63):  # seeds are mixed as 32-bit words: a larger one would repeat a smaller
        with pytest.raises(TeachingError, match="seed must be a whole number"):
            teacher.resolve_task(seed=seed)
        with pytest.raises(TeachingError, match="seed must be a whole number"):
            teacher.episode(TASK, seed=seed)
    with pytest.raises(TeachingError, match="closest is 'Move blue triangle to red square'"):
        teacher.resolve_task(instruction="move blue triangle to red squar")
    with pytest.raises(TeachingError, match="no English words"):
        teacher.resolve_task(instruction="把蓝色三角形移到红色方块")
    with pytest.raises(TeachingError, match="for example 'Move"):  # an instruction's example, not a correction's
        teacher.resolve_task(instruction="")


def test_the_log_is_one_parquet_row_per_attempt(teacher, tmp_path):
    episode = teacher.episode(TASK, seed=3, source="test")
    episode.attempt()
    write_episode_log(episode, tmp_path / "log")
    episode.hint()
    episode.attempt("enter the gry room")
    write_episode_log(episode, tmp_path / "log")  # replaces the episode's file
    other = teacher.episode(TASK + 1, seed=0)
    other.attempt()
    write_episode_log(other, tmp_path / "log")
    rows = pads.dataset(str(tmp_path / "log"), format="parquet").to_table().to_pylist()
    assert len(rows) == 3 and len(list((tmp_path / "log").iterdir())) == 2
    mine = sorted((r for r in rows if r["episode"] == episode.episode_id), key=lambda r: r["attempt"])
    assert [r["attempt"] for r in mine] == [0, 1]
    assert mine[1]["correction_before"] == "enter the gry room" and mine[1]["unknown_words"] == ["gry"]
    assert mine[1]["typed"] == "enter the gry room"  # sent as typed
    assert mine[1]["hint_shown"] and not mine[0]["hint_shown"] and mine[0]["correction_before"] == ""
    assert "correction" not in mine[0]  # the buffer's `correction` is the one after an attempt: not this
    assert mine[1]["correction_tokens"] == list(episode.attempts[1].check.token_ids)
    assert mine[0]["task_id"] == TASK and mine[0]["seed"] == 3 and mine[0]["source"] == "test"
    assert mine[1]["completion"] == episode.attempts[1].completion and mine[1]["started_at"] is not None
    assert not any(r["undone"] for r in mine)
    undone = episode.undo()
    again = episode.attempt("enter the grey room", typed="go into the grey rom")
    write_episode_log(episode, tmp_path / "log")
    rows = [r for r in pads.dataset(str(tmp_path / "log"), format="parquet").to_table().to_pylist()
            if r["episode"] == episode.episode_id]
    assert [(r["attempt"], r["correction_before"], r["undone"]) for r in rows] == [
        (0, "", False), (1, "enter the gry room", True), (1, "enter the grey room", False)]
    assert rows[2]["typed"] == "go into the grey rom"  # what the person typed, beside what was sent
    assert undone.key != again.key and len(episode.attempts) == 2
    with pytest.raises(TeachingError, match="no correction to undo"):
        other.undo()


def test_undo_is_exact_and_the_oracle_runs_beside_without_joining_the_episode(teacher):
    episode, fresh = teacher.episode(TASK, seed=3), teacher.episode(TASK, seed=3)
    episode.attempt()
    fresh.attempt()
    episode.attempt("enter the blue room")
    episode.undo()
    redone = episode.attempt("enter the grey room")
    assert np.array_equal(redone.actions, fresh.attempt("enter the grey room").actions)  # as if never undone
    episode.undo()
    hint = episode.hint()
    branch = episode.oracle_attempt()
    assert branch.said_before == hint and len(episode.attempts) == 1 and episode.oracle_branch == {1: branch}
    by_oracle = teacher.episode(TASK, seed=3)
    by_oracle.attempt()
    assert np.array_equal(branch.actions, by_oracle.attempt(hint).actions)
    for picture in (episode.gif(1, oracle=True), episode.still(1, oracle=True), episode.film_strip(1, oracle=True)):
        assert len(picture) > 1000
    with pytest.raises(TeachingError, match="does not exist"):
        episode.still(1)


def test_a_policy_that_reads_no_words_cannot_be_taught(tmp_path):
    run = _train(tmp_path / "instr", "model.variant=instruction_only")
    with pytest.raises(TeachingError, match="does not read corrections"):
        Teacher(run)


def test_teach_in_the_terminal(run, tmp_path, monkeypatch, capsys):
    typed = ["", "x" * 10_000, "enter\x1b[31m the room", "Geh nach Norden", ":hint", ":help", "enter the gry room", "",
             "the", ":use", ":undo", ":quit"]
    monkeypatch.setattr("sys.stdin", io.StringIO("\n".join(typed) + "\n"))
    assert main(["teach", "--run-dir", str(run), "--task", str(TASK), "--seed", "3", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for needle in ("'Move blue triangle to red square'", "(test split)", "attempt 1 (instruction", "empty", "at most 200",
                   "control characters", "knows too few of the words", "hint: the oracle would say",
                   "unknown command ':help'", "unknown words: gry", "closest known phrasing: 'enter the grey room'",
                   "attempt 2 (correction: 'enter the gry room')", "not a phrasing the policy was trained on",
                   "carrying", "GIF: ", "undone: attempt 3", "steps"):
        assert needle in out, needle
    gifs = sorted((tmp_path / "gifs").glob("*.gif"))
    assert len(gifs) == 3 and all(g.stat().st_size > 1000 for g in gifs)
    rows = pads.dataset(str(tmp_path / "log"), format="parquet").to_table().to_pylist()
    rows.sort(key=lambda r: r["attempt"])
    said = [r["correction_before"] for r in rows]
    assert said[:2] == ["", "enter the gry room"] and len(said) == 3 and said[2] != "the"  # ':use' sent the closest
    assert said[2] in MULTIROOM.correction_phrasings() and "attempt 3 (correction: '" + said[2] in out
    assert rows[2]["typed"] == "the" and rows[2]["undone"] and not rows[1]["undone"]  # ':undo' took it back
    assert rows[0]["run_dir"] == str(run.resolve()) and rows[0]["checkpoint"].endswith("checkpoints/latest.pt")
    assert rows[0]["split"] == "test" and rows[0]["greedy"] is False
    assert main(["teach", "--run-dir", str(run), "--task", "99999", "--out", str(tmp_path)]) == 2
    assert "outside 0..3239" in capsys.readouterr().err


def test_the_web_api_keeps_episodes_apart_and_answers_bad_input_in_one_sentence(teacher, tmp_path):
    from fastapi.testclient import TestClient

    from gpl_dist.app.teach_web import create_app

    client = TestClient(create_app(teacher, tmp_path), base_url="http://127.0.0.1")
    rebound = TestClient(create_app(teacher, tmp_path), base_url="http://attacker.example")
    assert rebound.get("/api/info").status_code == 400  # DNS rebinding: a foreign Host is refused
    a = client.post("/api/episodes", json={"task_id": TASK, "seed": 3}).json()
    b = client.post("/api/episodes", json={"task_id": TASK, "seed": 4}).json()
    assert a["episode_id"] != b["episode_id"] and len(a["attempts"]) == 1
    cases = [
        ("post", f"/api/episodes/{a['episode_id']}/attempts", {"correction": ""}, 400, "empty"),
        ("post", f"/api/episodes/{a['episode_id']}/attempts", {"correction": "y" * 10_000}, 400, "at most 200"),
        ("post", f"/api/episodes/{a['episode_id']}/attempts", {"correction": "go\u0000 north"}, 400, "control"),
        ("post", f"/api/episodes/{a['episode_id']}/attempts", {"correction": "向北走"}, 400, "no English words"),
        ("post", f"/api/episodes/{a['episode_id']}/attempts", {"correction": "z" * 100_000}, 422, "at most"),
        ("post", f"/api/episodes/{a['episode_id']}/attempts", {"text": "enter"}, 422, "correction"),
        ("post", "/api/episodes/nope/attempts", {"correction": "enter the blue room"}, 404, "start a new one"),
        ("post", "/api/episodes", {"task_id": 99999}, 400, "outside"),
        ("post", "/api/episodes", {"task_id": "seven"}, 422, "task_id"),
        ("post", "/api/episodes", {"task_id": True}, 422, "task_id"),
        ("post", "/api/episodes", {"task_id": 10**40}, 400, "digits) is outside"),
        ("post", "/api/episodes", {"task_id": 1, "seed": 2**32}, 422, "seed"),
        ("post", "/api/episodes", {"task_id": 1, "instruction": "move blue ball to red square"}, 400, "not both"),
        ("get", f"/api/episodes/{a['episode_id']}/attempts/5.gif", None, 400, "does not exist"),
    ]
    for method, path, body, status, needle in cases:
        r = client.post(path, json=body) if method == "post" else client.get(path)
        assert r.status_code == status and needle in r.json()["detail"], (path, body and str(body)[:30], r.text[:200])
        assert "\n" not in r.json()["detail"]
    b2 = client.post(f"/api/episodes/{b['episode_id']}/attempts", json={"correction": "enter the grey room"}).json()
    assert len(b2["attempts"]) == 2 and b2["attempts"][1]["said_before"] == "enter the grey room"
    a_now = client.post(f"/api/episodes/{a['episode_id']}/attempts", json={"correction": "enter the red room"}).json()
    assert [x["said_before"] for x in a_now["attempts"]][1:] == ["enter the red room"]  # nothing of b's
    gif = client.get(a_now["attempts"][1]["gif_url"])
    assert gif.status_code == 200 and gif.content[:6] == b"GIF89a"
    check = client.post("/api/check", json={"text": "enter the gry room"}).json()
    assert check["unknown_words"] == ["gry"] and check["suggestion"] == "enter the grey room"
    info = client.get("/api/info").json()
    assert info["example_instruction"].startswith("Move ")
    # the legend of the still pictures: the agent's path in the first path colour, then the ring
    assert info["legend"] == [{"colour": "#e62828", "meaning": "the path of the agent"},
                              {"colour": "#14c83c", "meaning": "the ring: where the task was first solved"}]
    assert client.get(f"/api/episodes/{a['episode_id']}/hint").json()["hint"]


def test_a_browser_teaches_a_full_episode(run, tmp_path):
    """Headless Chromium (Debian's, installed by .ci/run) through the page: load, first attempt,
    type a correction with an unknown word (highlighted), fix it, see the second attempt; a second
    tab's episode stays apart; a screenshot is saved."""
    from playwright.sync_api import expect, sync_playwright

    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "the browser test needs Debian's chromium (apt-get install chromium; .ci/run does)"
    port = free_ports(1)[0]
    server = subprocess.Popen([GPL_DIST, "serve", "--run-dir", str(run), "--port", str(port), "--out", str(tmp_path)],
                              env=quiet_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    try:
        wait_for_port(port, server)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=chromium, headless=True, args=["--no-sandbox"])
            page = browser.new_page()
            page.goto(f"http://127.0.0.1:{port}/")
            expect(page.locator("#run")).to_contain_text("multiroom policy (gpl)")
            page.fill("#task", str(TASK))
            page.fill("#seed", "3")
            page.click("#new")
            expect(page.locator(".attempt")).to_have_count(1, timeout=60_000)
            page.click("#send")  # an empty correction
            expect(page.locator("#message")).to_contain_text("empty")
            page.fill("#correction", "enter the gry room")
            expect(page.locator("#echo .unknown")).to_have_text("gry ", timeout=10_000)
            expect(page.locator("#suggestion")).to_contain_text('"enter the grey room"')
            page.fill("#correction", "enter the grey room")
            expect(page.locator("#echo .unknown")).to_have_count(0, timeout=10_000)
            page.click("#send")
            expect(page.locator(".attempt")).to_have_count(2, timeout=60_000)
            expect(page.locator(".attempt").nth(1)).to_contain_text("correction: enter the grey room")
            expect(page.locator(".attempt").nth(1)).to_contain_text("completion")
            page.wait_for_function("[...document.querySelectorAll('.attempt img')].every(i => i.complete && i.naturalWidth > 0)"
                                   " && document.querySelectorAll('.loading').length === 0", timeout=60_000)
            frames = page.locator(".attempt .frame")
            page.locator("#scrub").fill("0")  # one control moves every attempt: all at their first frame
            assert [frames.nth(i).get_attribute("data-frame") for i in range(2)] == ["0", "0"]
            page.locator("#scrub").fill("50")
            assert len({frames.nth(i).get_attribute("data-frame") for i in range(2)}) == 1
            assert frames.nth(0).get_attribute("data-frame") not in ("0", None)
            expect(page.locator(".attempt").nth(0).locator(".now")).to_contain_text("step 50")
            page.click("#oracle-button")  # the oracle's correction, its attempt beside (dashed), not added
            expect(page.locator(".attempt.oracle")).to_have_count(1, timeout=60_000)
            expect(page.locator("#hint")).to_contain_text("The oracle would say:")
            page.click("#undo")  # take "enter the grey room" back
            expect(page.locator(".attempt:not(.oracle)")).to_have_count(1, timeout=60_000)
            page.fill("#correction", "enter the gry room")
            page.locator("#use-suggestion").click(timeout=10_000)  # send the closest phrasing in its place
            page.click("#send")
            expect(page.locator(".attempt:not(.oracle)")).to_have_count(2, timeout=60_000)
            expect(page.locator(".attempt").nth(1)).to_contain_text("you typed: enter the gry room")
            with page.expect_download() as download:
                page.click("#download")
            session = tmp_path / "session.parquet"
            download.value.save_as(session)
            other = browser.new_page()  # a second tab: its own episode
            other.goto(f"http://127.0.0.1:{port}/")
            other.fill("#task", str(TASK + 1))
            other.click("#new")
            expect(other.locator(".attempt")).to_have_count(1, timeout=60_000)
            page.click("#hint-button")
            expect(page.locator("#hint")).to_contain_text("The oracle would say:")
            expect(page.locator(".attempt")).to_have_count(2)
            page.wait_for_function("document.querySelectorAll('.loading').length === 0", timeout=60_000)
            shot = tmp_path / "teach-page.png"
            page.screenshot(path=str(shot), full_page=True)
            browser.close()
        assert shot.stat().st_size > 10_000
        rows = pads.dataset(str(tmp_path / "log"), format="parquet").to_table().to_pylist()
        assert sorted((r["task_id"], r["attempt"], r["correction_before"], r["typed"], r["undone"], r["source"])
                      for r in rows) == [
            (TASK, 0, "", "", False, "web"), (TASK, 1, "enter the grey room", "enter the grey room", True, "web"),
            (TASK, 1, "enter the grey room", "enter the gry room", False, "web"),  # typed, and what was sent
            (TASK + 1, 0, "", "", False, "web")]
        import pyarrow.parquet as pq
        downloaded = pq.read_table(session).to_pylist()  # the same rows as the episode's log file
        assert downloaded == [r for r in rows if r["episode"] == downloaded[0]["episode"]] and len(downloaded) == 3
    finally:
        server.terminate()
        server.wait(timeout=30)


def test_serve_refuses_a_bad_port_split_or_taken_port_in_one_line(run, capsys):
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    try:
        for args, needle in ((["--port", "99999"], "1..65535"), (["--split", "nope"], "unknown split 'nope'"),
                             (["--port", str(taken.getsockname()[1])], "cannot listen on 127.0.0.1")):
            assert main(["serve", "--run-dir", str(run), *args]) == 2
            err = capsys.readouterr().err.strip()
            assert err.startswith("gpl-dist: error:") and needle in err and "\n" not in err, err
    finally:
        taken.close()


def test_twenty_requests_for_one_unfinished_gif_render_it_once(teacher, tmp_path):
    """Issue 41, item 7: concurrent requests for a picture in flight wait for that render (loopback
    server, bounded count); the cache and the renders at once are bounded, so memory is too."""
    import threading
    import urllib.request

    import psutil
    import uvicorn

    from gpl_dist.app.teach_web import create_app

    app = create_app(teacher, tmp_path)
    port = free_ports(1)[0]
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        while not server.started:
            time.sleep(0.05)
        base = f"http://127.0.0.1:{port}"
        request = urllib.request.Request(f"{base}/api/episodes", data=b'{"task_id": 263, "seed": 3}',
                                         headers={"Content-Type": "application/json"})
        view = json.loads(urllib.request.urlopen(request, timeout=300).read())
        url = base + view["attempts"][0]["gif_url"]
        process, bodies, peak = psutil.Process(), [], [0]
        before = process.memory_info().rss
        done = threading.Event()

        def watch():
            while not done.is_set():
                peak[0] = max(peak[0], process.memory_info().rss)
                time.sleep(0.02)

        def fetch():
            bodies.append(urllib.request.urlopen(url, timeout=300).read())

        watcher = threading.Thread(target=watch)
        watcher.start()
        clients = [threading.Thread(target=fetch) for _ in range(20)]
        for c in clients:
            c.start()
        for c in clients:
            c.join()
        done.set()
        watcher.join()
        assert len(bodies) == 20 and len(set(bodies)) == 1 and bodies[0][:6] == b"GIF89a"
        assert app.state.pictures.renders == 1  # drawn once; 19 waited for it
        assert peak[0] - before < 400 * 2**20  # one render's frames, not twenty (20 renders grew 1.7 GB)
        urllib.request.urlopen(url, timeout=300).read()
        assert app.state.pictures.renders == 1  # and kept for the next one
    finally:
        server.should_exit = True
        thread.join(timeout=30)


def test_teach_with_stdin_closed_ends_after_the_first_attempt(run, tmp_path):
    """``gpl-dist teach ... 0<&-`` (before: AttributeError on sys.stdin.isatty after the first attempt)."""
    done = subprocess.run(["bash", "-c", f"'{GPL_DIST}' teach --run-dir '{run}' --task {TASK} --out '{tmp_path}' 0<&-"],
                          env=quiet_env(), capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Traceback" not in done.stderr and "standard input is closed" in done.stdout
    assert list((tmp_path / "log").glob("*.parquet"))
