"""The console's Starlette application: the page, its live updates, sheets, frames and actions.

Routes (every one behind the token when the console listens beyond loopback, :class:`TokenGate`):

=============================  ==============================================================
``GET /``                      the page (``templates/console.html``): every panel drawn
``GET /stream``                server-sent events: the panels again whenever they change
                               (each second at most; the page swaps them in, no reload)
``GET /api/view``              the page's figures as JSON (scripts)
``GET /api/heliostats``        one page of the heliostats table, filtered and sorted
                               (:mod:`helicalib.console.table`: ``board``, ``verdict``,
                               ``state``, ``q``, ``min_error``, ``max_error``, ``sort``,
                               ``order``, ``offset``, ``limit``)
``GET /frames/{id}.png``       a board's newest before/after frames with the spot overlay
                               (:func:`helicalib.report.overlay.overlay_latest`)
``GET /progress.png``          acceptance over time (the report's plot)
``GET /heliostat/{id}``        the heliostat's sheet, drawn as the report draws it
``POST /api/action``           an operator action (JSON; only when the controller runs armed)
``/static/...``                the page's script and style sheet (no CDN: the plant LAN has no
                               internet)
=============================  ==============================================================

Pages come from Jinja2 templates with autoescaping (the console's folder first, then the
report's: ``base.html`` and ``macros.html`` are the report's own); no HTML is built in Python.
"""

from __future__ import annotations

import asyncio
import hmac
import json
import tempfile
import threading
import time
from pathlib import Path
from urllib.parse import quote

from helicalib.console.view import FRAMES_KEPT, STATES, Sources, read_view, reading
from helicalib.errors import ConfigError, DataError, HelicalibError

TEMPLATES = Path(__file__).with_name("templates")
STATIC = Path(__file__).with_name("static")
COOKIE = "helicalib_console"
PANELS = ("clock", "gate", "boards", "map", "progress", "events", "actions")
VIEW_EVERY_S = 1.0
"""The page's figures are read from the database at most this often (shared by every viewer)."""
VIEW_MAX_AGE_S = 30.0
"""``console DB`` reads the figures again after this long even when the database's files look unchanged."""
TABLE_EVERY_S = 5.0
"""The heliostats table's rows are read from the database at most this often."""
REPORT_EVERY_S = 30.0
"""The report-side figures (progress plot) are recomputed at most this often."""


class Console:
    """The state behind the app: where it reads, what it caches, who may act.

    Parameters
    ----------
    sources : Sources
        The read-only store, field config, campaign and site clock.
    feed : LiveFeed, optional
        The controller's snapshots and event version (None: ``helicalib console DB``, polling).
    act : callable, optional
        ``act(kind, heliostat_ids, who) -> action id``: records an operator action (only in an
        armed controller; None: read-only, the actions panel says so).
    token : str, optional
        Required on every request when set.
    """

    def __init__(self, sources: Sources, feed=None, act=None, token: str | None = None, title: str = "helicalib",
                 reopen=None):
        self.src, self.feed, self.act, self.token, self.title = sources, feed, act, token, title
        self.reopen = reopen
        """``reopen()`` → a fresh read-only store (``console DB``: each read sees a process that started since)."""
        self.closing = threading.Event()
        self.cache = Path(tempfile.mkdtemp(prefix="helicalib-console-"))
        self._lock = threading.Lock()
        self._view: tuple[float, object, dict] | None = None
        self._report: tuple[float, object, object, dict] | None = None
        self._table: tuple[float, dict, list] | None = None
        """(when, the view the rows were built with, the rows)."""
        self._files_seen = None
        self._panels: tuple[dict, dict] | None = None
        self._draw_lock = threading.Lock()

    # ------------------------------------------------------------------ figures
    def _files(self):
        """What says the database changed, for ``console DB`` (no feed): the database's and its
        WAL's modification times and sizes, and who holds it; None beside a controller (its
        snapshots change every second anyway)."""
        if self.feed is not None:
            return None
        path = Path(self.src.store.path)
        marks = []
        for f in (path, path.with_name(path.name + "-wal")):
            try:
                st = f.stat()
                marks.append((st.st_mtime_ns, st.st_size))
            except OSError:
                marks.append(None)
        return tuple(marks) + (self.src.store.owner(),)

    def view(self) -> dict:
        """The page's figures, read at most every :data:`VIEW_EVERY_S` or when an event came; for
        ``console DB``, only when the database's files changed (or :data:`VIEW_MAX_AGE_S` passed):
        at 10⁴ heliostats a read costs tenths of a second, and an open page asks every second."""
        snapshot, version = self.feed.latest() if self.feed is not None else (None, None)
        with self._lock:
            now = time.monotonic()
            files = self._files()
            if self._view is not None and self._view[1] == version and (
                    now - self._view[0] < VIEW_EVERY_S
                    or (files is not None and files == self._files_seen and now - self._view[0] < VIEW_MAX_AGE_S)):
                return self._view[2]
            self._files_seen = files
            if self.reopen is not None:
                old, self.src.store = self.src.store, self.reopen()
                old.close()
            with reading(self.src.store, self.src.campaign_id):
                v = read_view(self.src, snapshot)
            self._view = (now, version, v)
            return v

    def table_rows(self) -> list[dict]:
        """The heliostats table's rows (:func:`helicalib.console.table.table_rows`): built from the
        page's current figures, and at most every :data:`TABLE_EVERY_S` while those change (beside
        a controller, every second)."""
        from helicalib.console.table import table_rows

        with self._lock:
            fresh = self._table is not None and time.monotonic() - self._table[0] < TABLE_EVERY_S
        if fresh:  # paging, sorting and filtering within a few seconds: no read at all
            return self._table[2]
        v = self.view()
        with self._lock:
            if self._table is None or (self._table[1] is not v and time.monotonic() - self._table[0] >= TABLE_EVERY_S):
                with reading(self.src.store, self.src.campaign_id):
                    progress = self.src.store.progress(self.src.campaign_id)
                self._table = (time.monotonic(), v, table_rows(progress, v["states"], set(v["out_of_service"])))
            return self._table[2]

    def warm(self) -> None:
        """Read the page's figures once before the first viewer comes (the imports, the field's
        layout and every verdict: seconds at 10⁴ heliostats); a failure is left for the page to say."""
        try:
            self.map_positions()
            self.table_rows()
        except Exception:  # noqa: BLE001 - the page reports what cannot be read, with its line
            pass

    def map_positions(self) -> dict | None:
        """The canvas map's positions (None when the map is SVG or there is none)."""
        from helicalib.console.view import map_positions

        v = self.view()
        return map_positions(self.src) if v["map"].get("canvas") else None

    def close(self) -> None:
        """Stop the live streams (the server is stopping)."""
        self.closing.set()

    def remove_cache(self) -> None:
        """Delete the drawn frames, plots and sheets (once the server has stopped)."""
        import shutil

        shutil.rmtree(self.cache, ignore_errors=True)

    def render(self, name: str, **context) -> str:
        from helicalib.report.html import render

        return render(name, self.src.site, extra_dirs=(str(TEMPLATES),), states=STATES, title=self.title, sortable=False,
                      token_mode=self.token is not None, **context)

    def panels(self, v: dict) -> dict[str, str]:
        """The panels drawn from the figures ``v``; drawn once per figures (every open page's stream
        asks each second, and at 10⁴ heliostats drawing them costs tenths of a second)."""
        drawn = self._panels
        if drawn is not None and drawn[0] is v:
            return drawn[1]
        panels = {p: self.render(f"panel_{p}.html", v=v) for p in PANELS}
        self._panels = (v, panels)
        return panels

    def report_data(self):
        """(CampaignData, report figures) of the campaign, recomputed at most every :data:`REPORT_EVERY_S`."""
        from helicalib.report.build import compute
        from helicalib.report.data import load_campaign

        with self._draw_lock:
            now = time.monotonic()
            if self._report is None or now - self._report[0] >= REPORT_EVERY_S:
                with reading(self.src.store, self.src.campaign_id):
                    data = load_campaign(self.src.store.path, self.src.campaign_id, images_dir=self.src.frames_dir())
                    if self.src.cfg is not None:
                        data.cfg = data.cfg or self.src.cfg
                    self._report = (now, data, None, compute(data, self.src.site))
            return self._report[1], self._report[3]

    def progress_png(self) -> Path:
        from helicalib.report import plots

        _data, rep = self.report_data()
        path = self.cache / "progress.png"
        with self._draw_lock:
            stamp = self._report[0]
            if not path.exists() or self._report[2] != stamp:
                plots.plot_progress(progress_until(rep["progress"], self._now_s()), path, self.src.site)
                self._report = (self._report[0], self._report[1], stamp, self._report[3])
        return path

    def _now_s(self) -> float | None:
        """The plant time the page shows now (the newest view's clock)."""
        with self._lock:
            return None if self._view is None else self._view[2]["clock"]["time_s"]

    def frames_png(self, obs_id: int) -> Path | None:
        from helicalib.report.overlay import overlay_latest

        latest = self.src.frames.get(int(obs_id))
        if latest is None:
            return None
        path = self.cache / "frames" / f"{int(obs_id)}.png"
        if not path.exists():
            with reading(self.src.store, self.src.campaign_id):
                images = self.src.frames_dir()
            with self._draw_lock:
                drawn = overlay_latest(images, latest, self.src.cfg, path, width_px=800)
            if drawn["png"] is None:
                return None
            old = sorted(path.parent.glob("*.png"), key=lambda f: int(f.stem))[:-FRAMES_KEPT]
            for f in old:  # a week of visits must not fill the disk
                f.unlink(missing_ok=True)
        return path

    def sheet(self, heliostat_id: str) -> str:
        """Draw the heliostat's sheet (as the report does) into the cache; its path under ``/sheets/``."""
        from helicalib.report.build import write_sheet

        data, rep = self.report_data()
        with self._draw_lock:
            summary = write_sheet(data, rep, self.cache / "sheets", heliostat_id, self.src.site)
        return summary["href"]


def progress_until(pr: dict, now_s: float | None) -> dict:
    """The report's progress series carried on, unchanged, to the plant time ``now_s`` the page
    shows: early in a run the series holds one instant (an axis of years); after this, the time
    axis runs from the campaign's start to now."""
    times = list(pr.get("times_s") or [])
    if not times or now_s is None or not now_s > times[-1]:
        return pr
    out = dict(pr)
    for key, values in pr.items():
        if isinstance(values, list) and len(values) == len(times) and key != "times_s" and not key.endswith("spans_s"):
            out[key] = values + values[-1:]
    out["times_s"] = times + [float(now_s)]
    return out


# ---------------------------------------------------------------------------------------------- token
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]", "::1")
"""Host names a console without a token answers to (it listens on 127.0.0.1 only)."""


class TokenGate:
    """ASGI middleware: every request needs the token (``X-Helicalib-Token`` header, ``?token=``
    once, then the cookie it sets); without it: 401 and one line saying how to get in."""

    def __init__(self, app, token: str):
        self.app, self.token = app, token

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        from starlette.requests import Request
        from starlette.responses import PlainTextResponse

        req = Request(scope)
        given = req.headers.get("x-helicalib-token") or req.query_params.get("token") or req.cookies.get(COOKIE) or ""
        if not hmac.compare_digest(given.encode(), self.token.encode()):
            resp = PlainTextResponse("helicalib console: token required (open the address printed at start, "
                                     "with ?token=..., or send the X-Helicalib-Token header)\n", status_code=401)
            return await resp(scope, receive, send)
        if req.query_params.get("token"):
            async def send_with_cookie(message):
                if message["type"] == "http.response.start":
                    headers = list(message.get("headers", []))
                    headers.append((b"set-cookie", f"{COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict"
                                    .encode()))
                    message = dict(message, headers=headers)
                await send(message)

            return await self.app(scope, receive, send_with_cookie)
        return await self.app(scope, receive, send)


# ---------------------------------------------------------------------------------------------- actions
MAX_BODY_BYTES = 16 * 1024
"""An action's JSON body is read up to this size; a longer one is refused (413) unread."""
MAX_ACTION_IDS = 1000
"""Heliostats one action may name."""
MAX_ID_CHARS = 200
ACTION_FIELDS = ("kind", "heliostats", "who")


class BodyTooLarge(HelicalibError):
    """A request body over :data:`MAX_BODY_BYTES` (answered 413)."""


async def read_body(request, limit: int = MAX_BODY_BYTES) -> bytes:
    """The request's body, refused (:class:`BodyTooLarge`) past ``limit`` bytes: by its declared
    length before reading, else as soon as the bytes received pass it."""
    declared = request.headers.get("content-length")
    if declared is not None:
        if not declared.strip().isdigit():
            raise ConfigError(f"action: Content-Length {declared[:40]!r} is not a number")
        if int(declared) > limit:
            raise BodyTooLarge(f"action: body of {int(declared)} bytes refused (at most {limit} bytes)")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise BodyTooLarge(f"action: body over {limit} bytes refused")
        chunks.append(chunk)
    return b"".join(chunks)


def _no_constant(name: str):
    raise ValueError(f"{name} is not a number JSON allows")


def parse_action(raw: bytes) -> tuple[str, list[str], str]:
    """(kind, heliostat ids, who) of an action's JSON body, each of the right type and length;
    :class:`ConfigError` naming the field otherwise. Whether the kind and ids are known is
    :func:`helicalib.campaign.operation.crew.check_request`'s to say."""
    from helicalib.campaign.operation.crew import KINDS, MAX_WHO_CHARS

    try:
        body = json.loads(raw.decode("utf-8"), parse_constant=_no_constant)
    except UnicodeDecodeError:
        raise ConfigError("action: the body is not UTF-8 text") from None
    except RecursionError:
        raise ConfigError("action: the JSON is nested too deeply (an action is one flat object)") from None
    except ValueError as err:
        raise ConfigError(f"action: not JSON ({err})") from None
    if not isinstance(body, dict):
        raise ConfigError('action: the body must be one JSON object {"kind": ..., "who": ..., "heliostats": [...]}')
    extra = [k for k in body if k not in ACTION_FIELDS]
    if extra:
        raise ConfigError(f"action: unknown field {extra[0][:40]!r} (the fields are {', '.join(ACTION_FIELDS)})")
    kind, who, ids = body.get("kind"), body.get("who"), body.get("heliostats")
    if not isinstance(kind, str) or kind not in KINDS:
        shown = kind[:40] if isinstance(kind, str) else json.dumps(kind)[:40]
        raise ConfigError(f"action: 'kind' {shown!r} is not one of {', '.join(KINDS)}")
    if not isinstance(who, str):
        got = "null" if who is None else type(who).__name__
        raise ConfigError(f"action: 'who' must be text, your name (got {got})")
    if len(who) > MAX_WHO_CHARS:
        raise ConfigError(f"action: 'who' is longer than {MAX_WHO_CHARS} characters")
    if any(not ch.isprintable() for ch in who):
        raise ConfigError("action: 'who' holds control characters (a name is one line of text)")
    if ids is None:
        ids = []
    elif isinstance(ids, str):
        ids = ids.split(",")
    if not isinstance(ids, list) or not all(isinstance(h, str) for h in ids):
        raise ConfigError("action: 'heliostats' must be a list of ids or one comma-separated string")
    if len(ids) > MAX_ACTION_IDS:
        raise ConfigError(f"action: {len(ids)} heliostats named (at most {MAX_ACTION_IDS} per action)")
    long = next((h for h in ids if len(h) > MAX_ID_CHARS), None)
    if long is not None:
        raise ConfigError(f"action: heliostat id {long[:40]!r}... is longer than {MAX_ID_CHARS} characters")
    return kind, ids, who.strip()


# ---------------------------------------------------------------------------------------------- app
def create_app(console: Console):
    """The Starlette application of ``console``."""
    from starlette.applications import Starlette
    from starlette.concurrency import run_in_threadpool
    from starlette.middleware import Middleware
    from starlette.requests import Request
    from starlette.responses import FileResponse, HTMLResponse, JSONResponse, RedirectResponse, Response, \
        StreamingResponse
    from starlette.routing import Mount, Route
    from starlette.staticfiles import StaticFiles

    async def page(request: Request):
        v = await run_in_threadpool(console.view)
        panels = await run_in_threadpool(console.panels, v)
        positions = await run_in_threadpool(console.map_positions)
        return HTMLResponse(console.render("console.html", v=v, panels=panels, live=console.feed is not None,
                                           positions=positions))

    async def stream(request: Request):
        async def events():
            last: dict[str, str] = {}
            while not console.closing.is_set():
                if await request.is_disconnected():
                    break
                try:
                    v = await run_in_threadpool(console.view)
                    panels = await run_in_threadpool(console.panels, v)
                except HelicalibError as err:  # damaged data says so in one line; the stream goes on
                    panels = {"clock": console.render("panel_error.html", error=str(err))}
                except Exception as err:  # noqa: BLE001 - a page that cannot be read says so, the stream goes on
                    panels = {"clock": console.render("panel_error.html", error=f"{type(err).__name__}: {err}")}
                changed = {k: h for k, h in panels.items() if last.get(k) != h}
                if changed:
                    last.update(changed)
                    yield f"data: {json.dumps({'panels': changed})}\n\n"
                else:
                    yield ": idle\n\n"
                await asyncio.sleep(VIEW_EVERY_S)

        return StreamingResponse(events(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    async def api_view(request: Request):
        v = await run_in_threadpool(console.view)
        return JSONResponse(json.loads(json.dumps(v, default=str)))

    async def api_heliostats(request: Request):
        from helicalib.console.table import query

        rows = await run_in_threadpool(console.table_rows)
        try:
            page = query(rows, request.query_params)
        except ConfigError as err:
            return JSONResponse({"error": str(err)}, status_code=400)
        return JSONResponse(page)

    async def frames(request: Request):
        path = await run_in_threadpool(console.frames_png, int(request.path_params["obs"]))
        if path is None:
            return Response("frames not available\n", status_code=404, media_type="text/plain")
        return FileResponse(path, media_type="image/png", headers={"Cache-Control": "max-age=3600"})

    async def progress(request: Request):
        try:
            path = await run_in_threadpool(console.progress_png)
        except DataError:
            raise  # damaged data: 503 with its line (unreadable)
        except HelicalibError as err:
            return Response(f"{err}\n", status_code=404, media_type="text/plain")
        return FileResponse(path, media_type="image/png", headers={"Cache-Control": "no-store"})

    async def heliostat(request: Request):
        hid = request.path_params["hid"]
        try:
            href = await run_in_threadpool(console.sheet, hid)
        except DataError:
            raise
        except HelicalibError as err:
            return Response(f"{err}\n", status_code=404, media_type="text/plain")
        return RedirectResponse("/sheets/" + quote(href), status_code=303)

    async def action(request: Request):
        if console.act is None:
            return JSONResponse({"error": "read-only console: actions need the controller running with --arm and "
                                          "--console"}, status_code=403)
        if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
            return JSONResponse({"error": "actions are JSON requests (Content-Type: application/json)"},
                                status_code=415)
        origin = request.headers.get("origin")
        if origin and origin.split("://", 1)[-1] != request.headers.get("host"):
            return JSONResponse({"error": f"action refused: request from another site ({origin})"}, status_code=403)
        try:
            kind, ids, who = parse_action(await read_body(request))
            # the socket's peer: a header (X-Forwarded-For...) is whatever the sender wrote
            client = request.scope["client"][0] if request.scope.get("client") else "?"
            action_id = await run_in_threadpool(console.act, kind, ids, f"{who} ({client})" if who else "")
        except BodyTooLarge as err:
            return JSONResponse({"error": str(err)}, status_code=413)
        except HelicalibError as err:
            return JSONResponse({"error": str(err)}, status_code=400)
        return JSONResponse({"id": action_id, "kind": kind, "status": "recorded; the controller applies it at "
                                                                      "its next decision"})

    async def sheets_index(request: Request):
        return RedirectResponse("/", status_code=303)

    routes = [
        Route("/", page), Route("/stream", stream), Route("/api/view", api_view),
        Route("/api/heliostats", api_heliostats),
        Route("/api/action", action, methods=["POST"]), Route("/frames/{obs:int}.png", frames),
        Route("/progress.png", progress), Route("/heliostat/{hid:path}", heliostat),
        Route("/sheets/index.html", sheets_index),
        Mount("/sheets", app=StaticFiles(directory=console.cache / "sheets", check_dir=False)),
        Mount("/static", app=StaticFiles(directory=STATIC)),
    ]
    if console.token:
        middleware = [Middleware(TokenGate, token=console.token)]
    else:
        # loopback only: a request must name this machine as its host, or a web page whose domain
        # re-binds to 127.0.0.1 could read the console and act on an armed controller
        from starlette.middleware.trustedhost import TrustedHostMiddleware

        middleware = [Middleware(TrustedHostMiddleware, allowed_hosts=list(LOOPBACK_HOSTS))]
    (console.cache / "sheets").mkdir(parents=True, exist_ok=True)
    threading.Thread(target=console.warm, name="helicalib-console-warm", daemon=True).start()

    async def unreadable(request: Request, err: HelicalibError):
        """A database that cannot be read (damaged rows, a file gone): one line, 503, never a traceback."""
        line = " ".join(str(err).split())
        if request.url.path.startswith("/api/"):
            return JSONResponse({"error": line}, status_code=503)
        if request.url.path == "/":
            return HTMLResponse(console.render("console_error.html", error=line), status_code=503)
        return Response(line + "\n", status_code=503, media_type="text/plain")

    return Starlette(routes=routes, middleware=middleware, exception_handlers={HelicalibError: unreadable})
