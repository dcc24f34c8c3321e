"""``gpl-dist serve``: the teaching loop (``gpl_dist.app.teaching``) in a web page.

FastAPI (typed request and response models, validation of every field, a test client; Starlette
underneath) served by uvicorn, bound to 127.0.0.1 unless told otherwise. The page
(``gpl_dist/app/web/teach.html``) is one static file: it keeps its own episode id, so several tabs
teach separate episodes. The JSON API:

==========================================  =================================================
``GET  /api/info``                          the run: domain, checkpoint round, limits, examples
``POST /api/episodes``                      start an episode (task id, or an instruction, or a
                                            drawn task; a seed) and make its first attempt
``POST /api/episodes/{id}/attempts``        a correction, and the attempt that follows it
``POST /api/episodes/{id}/undo``            take the last correction back
``GET  /api/episodes/{id}/hint``            what the run's oracle would say now
``POST /api/episodes/{id}/oracle``          the next attempt with the oracle's correction, beside
                                            the episode (not added to it)
``GET  /api/episodes/{id}/log.parquet``     the episode's rows of the teaching log, as a file
``GET  /api/episodes/{id}/attempts/{k}.gif``  attempt ``k`` as an animated GIF (``?oracle=1``: the
                                            oracle's branch; so for the two below)
``GET  /api/episodes/{id}/attempts/{k}/strip.png``  its frames side by side (the page's player)
``GET  /api/episodes/{id}/attempts/{k}/still.png``  its final state, path drawn, solved step ringed
``POST /api/check``                         unknown words and the closest phrasing, as one types
==========================================  =================================================

Pictures are made by ``Pictures``: each once, however many requests wait for it (the later ones
wait for the render in flight), at most ``RENDERS_AT_ONCE`` at a time, and at most
``PICTURE_BUDGET_BYTES`` of them kept (least recently used go first; they are drawn again if asked).

A request that cannot be served answers 4xx with ``{"detail": "<one sentence>"}``; no request
changes any episode but its own. At most ``MAX_EPISODES`` episodes are kept (the oldest go first);
each is logged after every attempt under ``OUT/log``. A log that cannot be written answers 507 (no
space: a full disk, a spent quota) or 503 (any other cause) with the file and the cause in
``detail``, and the episode stays as it was before the request (the page says why; the next request
is served as usual). ``serve`` checks ``OUT`` before it listens (a folder in which a file can be
made) and holds ``OUT/.writers.lock`` while it serves (``teaching.teaching_writer``).

Memory: an episode holds its attempts' actions and states (kilobytes); a picture is drawn from the
frames it shows (``teaching.drawn_at``), one full-size frame at a time, and finished pictures share
``PICTURE_BUDGET_BYTES``.
"""

from __future__ import annotations

import ipaddress
import threading
from collections import OrderedDict
from concurrent.futures import Future
from pathlib import Path
from typing import Callable

from fastapi import FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.trustedhost import TrustedHostMiddleware
from fastapi.responses import HTMLResponse, JSONResponse, Response
from pydantic import BaseModel, Field, StrictInt

from gpl_dist.app.rendering import picture_legend
from gpl_dist.app.teaching import (
    MAX_SEED,
    MAX_TEXT_CHARS,
    STRIP_FRAME_PX,
    TaughtAttempt,
    Teacher,
    TeachingEpisode,
    TeachingError,
    TeachingWriteError,
    check_out_folder,
    episode_log_bytes,
    teaching_writer,
    write_episode_log,
)
from gpl_dist.splits import split_tasks

#: Episodes kept in memory at once; starting another forgets the least recently used.
MAX_EPISODES = 64
#: Longest text field a request may carry (longer ones are refused before any check): room for a
#: person's 10,000 characters to get the checker's message rather than a generic one.
MAX_FIELD_CHARS = 50 * MAX_TEXT_CHARS
_PAGE = Path(__file__).parent / "web" / "teach.html"
#: Pictures drawn at once (each holds an attempt's frames in memory while it is drawn).
RENDERS_AT_ONCE = 2
#: Bytes of finished pictures kept for later requests.
PICTURE_BUDGET_BYTES = 128 * 2**20


class Pictures:
    """Finished pictures by key, and the renders in flight: a picture asked for while it is being
    drawn is waited for, not drawn again (``renders`` counts the renders made)."""

    def __init__(self, budget_bytes: int = PICTURE_BUDGET_BYTES, at_once: int = RENDERS_AT_ONCE):
        self.budget_bytes = budget_bytes
        self.renders = 0
        self._done: OrderedDict[tuple, bytes] = OrderedDict()
        self._kept_bytes = 0
        self._pending: dict[tuple, Future] = {}
        self._lock = threading.Lock()
        self._slots = threading.BoundedSemaphore(at_once)

    def get(self, key: tuple, render: Callable[[], bytes]) -> bytes:
        with self._lock:
            if key in self._done:
                self._done.move_to_end(key)
                return self._done[key]
            waiting = self._pending.get(key)
            if waiting is None:
                mine: Future = Future()
                self._pending[key] = mine
        if waiting is not None:
            return waiting.result()
        try:
            with self._slots:
                data = render()
                self.renders += 1
        except BaseException as err:
            with self._lock:
                del self._pending[key]
            mine.set_exception(err)
            raise
        with self._lock:
            del self._pending[key]
            self._done[key] = data
            self._kept_bytes += len(data)
            while self._kept_bytes > self.budget_bytes and len(self._done) > 1:
                self._kept_bytes -= len(self._done.popitem(last=False)[1])
        mine.set_result(data)
        return data


class StartRequest(BaseModel):
    """Start an episode: ``task_id``, else a task of the split with ``instruction``, else a drawn one."""

    task_id: StrictInt | None = None
    instruction: str | None = Field(default=None, max_length=MAX_FIELD_CHARS)
    seed: StrictInt = Field(default=0, ge=0, le=MAX_SEED)


class CorrectionRequest(BaseModel):
    """The correction to send, and what the person typed when it is the closest phrasing put in its place."""

    correction: str = Field(max_length=MAX_FIELD_CHARS)
    typed: str | None = Field(default=None, max_length=MAX_FIELD_CHARS)


class CheckRequest(BaseModel):
    """Text to check as it is typed."""

    text: str = Field(max_length=MAX_FIELD_CHARS)


class CheckView(BaseModel):
    """``CorrectionCheck`` as the page reads it."""

    words: list[str]
    unknown_words: list[str]
    suggestion: str | None
    problem: str | None
    warning: str | None = None


class AttemptView(BaseModel):
    """One attempt as the page shows it: ``strip_steps`` are the steps of the frames in its strip."""

    index: int
    said_before: str
    typed: str
    unknown_words: list[str]
    completion: float
    success: bool
    solved_at: int | None
    steps: int
    gif_url: str
    strip_url: str
    still_url: str
    strip_steps: list[int]
    strip_frame_px: int
    picture: str


class EpisodeView(BaseModel):
    """An episode as the page shows it."""

    episode_id: str
    task_id: int
    split: str
    seed: int
    instruction: str
    solved: bool
    corrections_left: int
    attempts: list[AttemptView]
    oracle: AttemptView | None


class Episodes:
    """The episodes being taught, by id, least recently used first; one lock per episode."""

    def __init__(self, limit: int = MAX_EPISODES):
        self.limit = limit
        self._items: OrderedDict[str, tuple[TeachingEpisode, threading.Lock]] = OrderedDict()
        self._lock = threading.Lock()

    def add(self, episode: TeachingEpisode) -> None:
        with self._lock:
            self._items[episode.episode_id] = (episode, threading.Lock())
            while len(self._items) > self.limit:
                self._items.popitem(last=False)

    def get(self, episode_id: str) -> tuple[TeachingEpisode, threading.Lock]:
        with self._lock:
            if episode_id not in self._items:
                raise HTTPException(404, "no such episode (a restarted server or an old one forgotten): start a new one")
            self._items.move_to_end(episode_id)
            return self._items[episode_id]


def _attempt_view(episode: TeachingEpisode, a: TaughtAttempt, oracle: bool = False) -> AttemptView:
    base = f"/api/episodes/{episode.episode_id}/attempts/{a.index}"
    query = f"?v={a.key}" + ("&oracle=1" if oracle else "")  # a new attempt in an undone one's place: a new URL
    return AttemptView(index=a.index, said_before=a.said_before, typed=a.typed,
                       unknown_words=list(a.check.unknown_words) if a.check else [],
                       completion=a.completion, success=a.success, solved_at=a.solved_at, steps=len(a.actions),
                       picture=a.picture, gif_url=f"{base}.gif{query}", strip_url=f"{base}/strip.png{query}",
                       still_url=f"{base}/still.png{query}", strip_steps=episode.strip_steps(a.index, oracle),
                       strip_frame_px=STRIP_FRAME_PX)


def _view(episode: TeachingEpisode) -> EpisodeView:
    attempts = [_attempt_view(episode, a) for a in episode.attempts]
    n = len(episode.attempts)  # the oracle's attempt at the next index, or beside the person's latest
    branch = episode.oracle_branch.get(n) or (episode.oracle_branch.get(n - 1) if n > 1 else None)
    return EpisodeView(episode_id=episode.episode_id, task_id=episode.task_id, split=episode.split, seed=episode.seed,
                       instruction=episode.instruction, solved=episode.solved,
                       corrections_left=episode.corrections_left, attempts=attempts,
                       oracle=_attempt_view(episode, branch, oracle=True) if branch else None)


def create_app(teacher: Teacher, out_dir: Path, split: str = "test", host: str = "127.0.0.1") -> FastAPI:
    """The web app teaching ``teacher``'s policy; logs under ``out_dir/log``. Served on a loopback
    ``host``, it answers only requests addressed to a loopback name (no DNS rebinding)."""
    split_tasks(teacher.domain.name, split)  # an unknown split fails here, naming the known ones
    check_out_folder(out_dir)  # a file, or a folder that takes no file, fails here rather than at each request
    app = FastAPI(title="gpl-dist teach", docs_url=None, redoc_url=None, openapi_url=None)
    if _is_loopback(host):
        app.add_middleware(TrustedHostMiddleware, allowed_hosts=["127.0.0.1", "localhost", "[::1]"])
    episodes = Episodes()
    pictures = app.state.pictures = Pictures()
    log_dir = out_dir / "log"
    domain = teacher.domain

    @app.exception_handler(TeachingError)
    async def teaching_error(request: Request, err: TeachingError) -> JSONResponse:
        return JSONResponse({"detail": str(err)}, status_code=400)

    @app.exception_handler(TeachingWriteError)
    async def not_written(request: Request, err: TeachingWriteError) -> JSONResponse:
        return JSONResponse({"detail": f"not saved, nothing changed: {err}"[:600]},
                            status_code=507 if err.no_space else 503)

    @app.exception_handler(RequestValidationError)
    async def bad_request(request: Request, err: RequestValidationError) -> JSONResponse:
        first = err.errors()[0] if err.errors() else {}
        where = ".".join(str(x) for x in first.get("loc", ()) if x != "body")
        return JSONResponse({"detail": f"{where or 'request'}: {first.get('msg', 'not valid')}"[:300]}, status_code=422)

    @app.get("/", response_class=HTMLResponse)
    def page() -> str:
        return _PAGE.read_text()

    @app.get("/favicon.ico")
    def favicon() -> Response:
        return Response(status_code=204)

    legend = [{"colour": c, "meaning": m} for c, m in picture_legend(domain)]  # an env built once per server

    @app.get("/api/info")
    def info() -> dict:
        return {"domain": domain.name, "run_dir": teacher.run_dir, "checkpoint_round": teacher.round_index,
                "variant": teacher.cfg.model.variant, "num_tasks": domain.num_tasks, "split": split,
                "max_corrections": teacher.max_corrections, "max_text_chars": MAX_TEXT_CHARS,
                "examples": teacher.examples(),  # the kind (and paraphrases) this policy trained on
                "legend": legend,
                "example_instruction": domain.instruction_of(split_tasks(domain.name, split)[0])}

    @app.post("/api/check", response_model=CheckView)
    def check(body: CheckRequest) -> CheckView:
        c = teacher.check(body.text)
        return CheckView(words=list(c.words)[:100], unknown_words=list(c.unknown_words)[:100],
                         suggestion=c.suggestion, problem=c.problem, warning=c.warning)

    @app.post("/api/episodes", response_model=EpisodeView)
    def start(body: StartRequest) -> EpisodeView:
        if body.task_id is not None and body.instruction:
            raise TeachingError("give a task id or an instruction, not both")
        task_id = teacher.resolve_task(body.task_id, body.instruction, body.seed, split)
        episode = teacher.episode(task_id, body.seed, "web")
        episode.attempt()
        write_episode_log(episode, log_dir)
        episodes.add(episode)
        return _view(episode)

    def changing(episode_id: str, change: Callable[[TeachingEpisode], object], busy: str) -> EpisodeView:
        episode, lock = episodes.get(episode_id)
        if not lock.acquire(blocking=False):
            raise HTTPException(409, busy)
        try:
            episode.logged(change, log_dir)  # a failed write puts the episode back as it was
            return _view(episode)
        finally:
            lock.release()

    @app.post("/api/episodes/{episode_id}/attempts", response_model=EpisodeView)
    def correct(episode_id: str, body: CorrectionRequest) -> EpisodeView:
        return changing(episode_id, lambda e: e.attempt(body.correction, body.typed),
                        "this episode is making an attempt already: wait for it")

    @app.post("/api/episodes/{episode_id}/undo", response_model=EpisodeView)
    def undo(episode_id: str) -> EpisodeView:
        return changing(episode_id, lambda e: e.undo(), "this episode is making an attempt: undo after it")

    @app.post("/api/episodes/{episode_id}/oracle", response_model=EpisodeView)
    def oracle(episode_id: str) -> EpisodeView:
        return changing(episode_id, lambda e: e.oracle_attempt(), "this episode is making an attempt: ask after it")

    @app.get("/api/episodes/{episode_id}/hint")
    def hint(episode_id: str) -> dict:
        episode, lock = episodes.get(episode_id)
        if not lock.acquire(blocking=False):  # a hint now would be logged against the attempt in flight
            raise HTTPException(409, "this episode is making an attempt: ask for the hint after it")
        try:
            return {"hint": episode.hint()}
        finally:
            lock.release()

    @app.get("/api/episodes/{episode_id}/log.parquet")
    def download(episode_id: str) -> Response:
        episode, lock = episodes.get(episode_id)
        with lock:
            data = episode_log_bytes(episode)
        return Response(data, media_type="application/vnd.apache.parquet",
                        headers={"Content-Disposition": f'attachment; filename="teaching-{episode.episode_id}.parquet"'})

    def picture(episode_id: str, index: int, oracle: int, kind: str, media: str) -> Response:
        episode, _ = episodes.get(episode_id)
        a = episode.find(index, bool(oracle))
        draw = {"gif": episode.gif, "strip": episode.film_strip, "still": episode.still}[kind]
        data = pictures.get((episode_id, a.key, kind), lambda: draw(index, bool(oracle)))
        return Response(data, media_type=media, headers={"Cache-Control": "max-age=3600"})

    @app.get("/api/episodes/{episode_id}/attempts/{index}.gif")
    def gif(episode_id: str, index: int, oracle: int = 0) -> Response:
        return picture(episode_id, index, oracle, "gif", "image/gif")

    @app.get("/api/episodes/{episode_id}/attempts/{index}/strip.png")
    def strip(episode_id: str, index: int, oracle: int = 0) -> Response:
        return picture(episode_id, index, oracle, "strip", "image/png")

    @app.get("/api/episodes/{episode_id}/attempts/{index}/still.png")
    def still(episode_id: str, index: int, oracle: int = 0) -> Response:
        return picture(episode_id, index, oracle, "still", "image/png")

    return app


def serve(teacher: Teacher, out_dir: Path, host: str = "127.0.0.1", port: int = 8000, split: str = "test") -> None:
    """Serve the page until interrupted; warns when ``host`` is reachable from other machines."""
    import socket

    import uvicorn

    if not 1 <= port <= 65535:
        raise TeachingError(f"--port must be in 1..65535, got {port}")
    split_tasks(teacher.domain.name, split)  # an unknown split fails here, before anything is made
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        try:  # a taken port fails in one line here rather than in uvicorn's log
            probe.bind((host, port))
        except OSError as err:
            raise TeachingError(f"cannot listen on {host}:{port}: {err.strerror or err}") from None
    with teaching_writer(out_dir):  # --out: a folder that takes a file, or one line here, before anything listens
        app = create_app(teacher, out_dir, split, host)
        if not _is_loopback(host):
            print(f"warning: serving on {host}: anyone who can reach this machine can use the page and its log")
        print(f"teaching {teacher.run_dir} ({teacher.domain.name}, round {teacher.round_index}) at http://{host}:{port}/",
              flush=True)
        uvicorn.run(app, host=host, port=port, log_level="warning")


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False
