"""Serving the console: the address and token rules, uvicorn in a thread, and the controller's hook.

* ``--console [HOST:]PORT`` binds 127.0.0.1 unless a host is given; a host beyond loopback is
  refused without ``--console-public``. With ``--console-public`` (whatever the host) every request
  needs the token printed at start (:class:`~helicalib.console.app.TokenGate`).
* The server runs in a daemon thread of the controller's process (its own event loop); it reads
  the database through a read-only connection of its own and the runner's snapshots through a
  :class:`~helicalib.console.feed.LiveFeed`, so the control loop never waits on a page.
* :func:`attach_console` is the one line a live session (``run``, ``operate``, ``check``:
  :mod:`helicalib.app.session`) adds after building its runner, with the :class:`ConsoleOptions`
  read from its arguments.
"""

from __future__ import annotations

import ipaddress
import secrets
import socket
import threading
import time
from dataclasses import dataclass

from helicalib.errors import ConfigError

DEFAULT_HOST = "127.0.0.1"


def parse_address(text: str, public: bool, option: str = "--console") -> tuple[str, int]:
    """``[HOST:]PORT`` → (host, port); a host beyond loopback needs ``public`` (one-line :class:`ConfigError`)."""
    raw = str(text).strip()
    host, _, port_text = raw.rpartition(":")
    host = host.strip("[]") or DEFAULT_HOST
    try:
        port = int(port_text)
    except ValueError:
        raise ConfigError(f"{option} {raw!r}: expected [HOST:]PORT (e.g. 8765 or 0.0.0.0:8765)") from None
    if not 0 <= port <= 65535:
        raise ConfigError(f"{option} {raw!r}: port {port} is not in 0..65535")
    if not public and not is_loopback(host):
        raise ConfigError(f"{option} {raw!r}: listening beyond loopback needs --console-public (every request then "
                          "needs the token printed at start)")
    return host, port


@dataclass(frozen=True)
class ConsoleOptions:
    """The crew console a controller command was asked for: ``--console [HOST:]PORT`` (None: no
    page), ``--console-public`` and ``--json`` (the page's address is then also a JSON line)."""

    console: str | None = None
    console_public: bool = False
    json: bool = False

    @classmethod
    def from_args(cls, args) -> ConsoleOptions:
        """The options of a parsed command line (a command without them asks for no page)."""
        return cls(console=getattr(args, "console", None), console_public=bool(getattr(args, "console_public", False)),
                   json=bool(getattr(args, "json", False)))

    def check(self) -> None:
        """Refuse a wrong ``--console`` / ``--console-public`` before anything starts (one line)."""
        if self.console:
            parse_address(self.console, self.console_public)
        elif self.console_public:
            raise ConfigError("--console-public: needs --console [HOST:]PORT")


def check_console_args(args) -> None:
    """Refuse a wrong ``--console`` / ``--console-public`` before anything starts (one line)."""
    ConsoleOptions.from_args(args).check()


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class ConsoleServer:
    """uvicorn serving ``app`` on ``host:port`` in a daemon thread (:meth:`start`, :meth:`stop`)."""

    def __init__(self, app, host: str, port: int, option: str = "--console"):
        self.app, self.host, self.port, self.option = app, host, port, option
        self._server = None
        self._thread = None
        self._sock = None

    def bind(self) -> None:
        """Take the port now (one line naming it when it is taken)."""
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((self.host, self.port))
        except OSError as err:
            sock.close()
            raise ConfigError(f"{self.option} {self.host}:{self.port}: cannot listen ({err.strerror or err})") from None
        sock.listen(64)
        sock.setblocking(False)
        self._sock = sock
        self.port = sock.getsockname()[1]

    def _config(self):
        import uvicorn

        # proxy_headers off: uvicorn would otherwise take X-Forwarded-For from a loopback peer as the
        # client, and an action would record whatever address its sender wrote
        return uvicorn.Config(self.app, log_level="warning", lifespan="off", access_log=False,
                              timeout_graceful_shutdown=2, proxy_headers=False)

    def start(self) -> None:
        """Serve in a daemon thread; returns once the server accepts connections."""
        import uvicorn

        if self._sock is None:
            self.bind()
        self._server = uvicorn.Server(self._config())
        self._thread = threading.Thread(target=self._server.run, kwargs={"sockets": [self._sock]},
                                        name="helicalib-console", daemon=True)
        self._thread.start()
        t0 = time.monotonic()
        while not self._server.started and self._thread.is_alive() and time.monotonic() - t0 < 10.0:
            time.sleep(0.02)

    def serve_forever(self) -> None:
        """Serve in this thread until Ctrl-C (``helicalib console DB``)."""
        import uvicorn

        if self._sock is None:
            self.bind()
        self._server = uvicorn.Server(self._config())
        self._server.run(sockets=[self._sock])

    def stop(self) -> None:
        if self._server is not None:
            self._server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self._sock is not None:
            self._sock.close()


def url(host: str, port: int, token: str | None) -> str:
    shown = f"[{host}]" if ":" in host else host
    return f"http://{shown}:{port}/" + (f"?token={token}" if token else "")


def attach_console(options: ConsoleOptions, runner, output):
    """The controller's hook: operator actions, and the page when ``options.console`` is set.

    An armed runner always gets its :class:`~helicalib.campaign.operation.crew.OperatorDesk` (what the
    crew's earlier actions left, paused or out of service, holds with or without a page). With
    ``--console`` the page is served from now until the run's output stops, and its address
    (with the token when needed) is said on ``output``. Returns the output ``run_live`` gets."""
    from helicalib.campaign.operation.crew import OperatorDesk
    from helicalib.console.app import Console, create_app
    from helicalib.console.feed import LiveFeed, Tee
    from helicalib.console.view import Sources
    from helicalib.geometry.sitetime import site_time
    from helicalib.store.sqlite import Store

    if runner.state.armed:
        runner.state.operator = OperatorDesk(runner.devices.store, runner.campaign_id)
        runner.state.operator.restore(runner)
    address = options.console
    if not address:
        return output
    public = bool(options.console_public)
    host, port = parse_address(address, public)
    token = secrets.token_urlsafe(18) if public else None
    reader = Store.open(runner.devices.store.path, runner.devices.store.images_dir, readonly=True)
    feed = LiveFeed()
    sources = Sources(store=reader, cfg=runner.cfg, campaign_id=runner.campaign_id, site=site_time(runner.cfg),
                      armed_actions=runner.state.armed, images_dir=runner.devices.store.images_dir)

    def act(kind, ids, who):
        from helicalib.campaign.operation.crew import check_request

        ids = check_request(kind, ids, set(runner.state.ids), who)
        try:
            plant_s = runner.devices.clock.estimate_s()
        except Exception:  # noqa: BLE001 - the wall clock is recorded anyway
            plant_s = None
        action_id = runner.devices.store.request_action(campaign_id=runner.campaign_id, kind=kind, heliostat_ids=ids,
                                                who=who, requested_wall_s=time.time(), requested_s=plant_s)
        feed.bump()
        return action_id

    console = Console(sources, feed=feed, act=act if runner.state.armed else None, token=token,
                      title=f"helicalib · {runner.cfg.site.name}")
    server = ConsoleServer(create_app(console), host, port)
    server.bind()
    server.start()
    output.message(f"console: {url(host, server.port, token)}"
                   + (" (the token is required on every request)" if token else " (this machine only)")
                   + ("" if runner.state.armed else "; read-only: actions need --arm"))
    if options.json and hasattr(output, "emit"):
        output.emit({"event": "console", "url": url(host, server.port, token), "token": token})

    def stop():
        console.close()
        server.stop()
        reader.close()
        console.remove_cache()

    tee = Tee(output, feed, on_stop=stop)
    runner.journal.listeners[:] = [tee.on_event if fn == output.on_event else fn for fn in runner.journal.listeners]
    tee.server, tee.console = server, console
    return tee
