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
``GET  /api/episodes/{id}/hint``            what the run's oracle would say now
``GET  /api/episodes/{id}/attempts/{k}.gif``  attempt ``k`` as an animated GIF
``POST /api/check``                         unknown words and the closest phrasing, as one types
==========================================  =================================================

A request that cannot be served answers 4xx with ``{"detail": "<one sentence>"}``; no request
changes any episode but its own. At most ``MAX_EPISODES`` episodes are kept (the oldest go first);
each is logged after every attempt under ``OUT/log``.
"""

from __future__ import annotations

import ipaddress
import threading
from collections import OrderedDict
from pathlib import Path

from fastapi import FastAPI, HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.trustedhost import TrustedHostMiddleware
from fastapi.responses import HTMLResponse, JSONResponse, Response
from pydantic import BaseModel, Field, StrictInt

from gpl_dist.app.teaching import (
    MAX_SEED,
    MAX_TEXT_CHARS,
    Teacher,
    TeachingEpisode,
    TeachingError,
    check_correction,
    instruction_of,
    write_episode_log,
)
from gpl_dist.splits import split_tasks

#: Episodes kept in memory at once; starting another forgets the least recently used.
MAX_EPISODES = 64
#: Longest text field a request may carry (longer ones are refused before any check): room for a
#: person's 10,000 characters to get the checker's message rather than a generic one.
MAX_FIELD_CHARS = 50 * MAX_TEXT_CHARS
_PAGE = Path(__file__).parent / "web" / "teach.html"


class StartRequest(BaseModel):
    """Start an episode: ``task_id``, else a task of the split with ``instruction``, else a drawn one."""

    task_id: StrictInt | None = None
    instruction: str | None = Field(default=None, max_length=MAX_FIELD_CHARS)
    seed: StrictInt = Field(default=0, ge=0, le=MAX_SEED)


class CorrectionRequest(BaseModel):
    """The correction a person typed."""

    correction: str = Field(max_length=MAX_FIELD_CHARS)


class CheckRequest(BaseModel):
    """Text to check as it is typed."""

    text: str = Field(max_length=MAX_FIELD_CHARS)


class CheckView(BaseModel):
    """``CorrectionCheck`` as the page reads it."""

    words: list[str]
    unknown_words: list[str]
    suggestion: str | None
    problem: str | None


class AttemptView(BaseModel):
    """One attempt as the page shows it."""

    index: int
    said_before: str
    unknown_words: list[str]
    completion: float
    success: bool
    gif_url: str
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


def _view(episode: TeachingEpisode) -> EpisodeView:
    attempts = [AttemptView(index=a.index, said_before=a.said_before,
                            unknown_words=list(a.check.unknown_words) if a.check else [],
                            completion=a.completion, success=a.success, picture=a.picture,
                            gif_url=f"/api/episodes/{episode.episode_id}/attempts/{a.index}.gif")
                for a in episode.attempts]
    return EpisodeView(episode_id=episode.episode_id, task_id=episode.task_id, split=episode.split, seed=episode.seed,
                       instruction=episode.instruction, solved=episode.solved,
                       corrections_left=episode.corrections_left, attempts=attempts)


def create_app(teacher: Teacher, out_dir: Path, split: str = "test", host: str = "127.0.0.1") -> FastAPI:
    """The web app teaching ``teacher``'s policy; logs under ``out_dir/log``. Served on a loopback
    ``host``, it answers only requests addressed to a loopback name (no DNS rebinding)."""
    split_tasks(teacher.domain.name, split)  # an unknown split fails here, naming the known ones
    app = FastAPI(title="gpl-dist teach", docs_url=None, redoc_url=None, openapi_url=None)
    if _is_loopback(host):
        app.add_middleware(TrustedHostMiddleware, allowed_hosts=["127.0.0.1", "localhost", "[::1]"])
    episodes = Episodes()
    log_dir = out_dir / "log"
    domain = teacher.domain

    @app.exception_handler(TeachingError)
    async def teaching_error(request: Request, err: TeachingError) -> JSONResponse:
        return JSONResponse({"detail": str(err)}, status_code=400)

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

    @app.get("/api/info")
    def info() -> dict:
        phrasings = domain.correction_phrasings() if domain.correction_phrasings else ()
        return {"domain": domain.name, "run_dir": teacher.run_dir, "checkpoint_round": teacher.round_index,
                "variant": teacher.cfg.model.variant, "num_tasks": domain.num_tasks, "split": split,
                "max_corrections": teacher.max_corrections, "max_text_chars": MAX_TEXT_CHARS,
                "examples": list(phrasings[:: max(1, len(phrasings) // 6)][:6]),
                "example_instruction": instruction_of(domain, split_tasks(domain.name, split)[0])}

    @app.post("/api/check", response_model=CheckView)
    def check(body: CheckRequest) -> CheckView:
        c = check_correction(domain, body.text, vocabulary=teacher.model.vocabulary)
        return CheckView(words=list(c.words)[:100], unknown_words=list(c.unknown_words)[:100],
                         suggestion=c.suggestion, problem=c.problem)

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

    @app.post("/api/episodes/{episode_id}/attempts", response_model=EpisodeView)
    def correct(episode_id: str, body: CorrectionRequest) -> EpisodeView:
        episode, lock = episodes.get(episode_id)
        if not lock.acquire(blocking=False):
            raise HTTPException(409, "this episode is making an attempt already: wait for it")
        try:
            episode.attempt(body.correction)
            write_episode_log(episode, log_dir)
        finally:
            lock.release()
        return _view(episode)

    @app.get("/api/episodes/{episode_id}/hint")
    def hint(episode_id: str) -> dict:
        episode, lock = episodes.get(episode_id)
        if not lock.acquire(blocking=False):  # a hint now would be logged against the attempt in flight
            raise HTTPException(409, "this episode is making an attempt: ask for the hint after it")
        try:
            return {"hint": episode.hint()}
        finally:
            lock.release()

    @app.get("/api/episodes/{episode_id}/attempts/{index}.gif")
    def gif(episode_id: str, index: int) -> Response:
        episode, _ = episodes.get(episode_id)
        return Response(episode.gif(index), media_type="image/gif", headers={"Cache-Control": "max-age=3600"})

    return app


def serve(teacher: Teacher, out_dir: Path, host: str = "127.0.0.1", port: int = 8000, split: str = "test") -> None:
    """Serve the page until interrupted; warns when ``host`` is reachable from other machines."""
    import socket

    import uvicorn

    if not 1 <= port <= 65535:
        raise TeachingError(f"--port must be in 1..65535, got {port}")
    app = create_app(teacher, out_dir, split, host)  # an unknown split fails here, before anything listens
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET) as probe:
        try:  # a taken port fails in one line here rather than in uvicorn's log
            probe.bind((host, port))
        except OSError as err:
            raise TeachingError(f"cannot listen on {host}:{port}: {err.strerror or err}") from None
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
