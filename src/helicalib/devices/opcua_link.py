"""The link to an OPC UA server: an asyncua client on its own event-loop thread behind a
synchronous, thread-safe :meth:`OpcUaLink.call` (the only place that connects, retries and says a
plant is unreachable). :class:`~helicalib.devices.opcua.OpcUaPlant` speaks the plant interface over it.

A lost connection, a timeout or a link status code is retried once after reconnecting; then
:class:`~helicalib.devices.protocols.PlantUnreachableError`. A request that acts on the plant (a
method Call) is never sent a second time once it may have reached the server: :class:`CallInDoubt`
lets the caller find out whether the plant took it. A UaError not raised on the wire (a value its
type cannot carry) is the request's fault, not the link's: one :class:`PlantError`, no retry.
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from asyncua import Client, ua
from asyncua.crypto import security_policies, uacrypto

from helicalib.devices.nodemap import is_node_id
from helicalib.devices.protocols import PlantUnreachableError
from helicalib.errors import PlantError

LINK_CODES = frozenset(getattr(ua.StatusCodes, n) for n in (
    "BadConnectionClosed", "BadSessionIdInvalid", "BadSessionClosed", "BadSecureChannelIdInvalid",
    "BadSecureChannelClosed", "BadTimeout", "BadCommunicationError", "BadServerNotConnected",
    "BadNotConnected", "BadSessionNotActivated", "BadRequestInterrupted", "BadShutdown",
    "BadServerHalted", "BadDisconnect"))
"""Status codes that say the link failed, not the plant: reconnect and retry."""


@dataclass(frozen=True)
class Security:
    """How the client secures its channel and who it logs in as."""

    policy: str = "None"
    mode: str = "SignAndEncrypt"
    certificate: str | None = None
    private_key: str | None = None
    server_certificate: str | None = None
    username: str | None = None
    password: str | None = None


class _LinkDown(Exception):
    """The link failed (not the plant's answer): reconnect and retry."""


class CallInDoubt(Exception):
    """A request that acts on the plant failed after it may have reached the server: not resent."""


def quiet_asyncua() -> None:
    """Silence asyncua's own log (its connection and session lines would reach stderr through
    Python's last-resort handler): a failure is one :class:`PlantError` line of ours."""
    logging.getLogger("asyncua").setLevel(logging.CRITICAL)


def _status_name(code) -> str:
    return ua.StatusCode(code).name if not isinstance(code, ua.StatusCode) else code.name


class OpcUaLink:
    """One OPC UA endpoint: an asyncua client on an event loop thread, connected on first use,
    reconnected once per failed call (thread-safe).

    ``down_s``: after a call failed every attempt, further calls fail at once for this many real
    seconds (a tick asking 500 heliostats must not wait 500 timeouts).
    """

    def __init__(self, endpoint: str, timeout_s: float = 4.0, security: Security | None = None,
                 down_s: float = 5.0, monotonic: Callable[[], float] = time.monotonic):
        self.endpoint = endpoint
        self.timeout_s = float(timeout_s)
        self.security = security or Security()
        self.down_s = down_s
        self.attempts = 2
        self._monotonic = monotonic
        self._down_until = -math.inf
        self._down_reason = ""
        self._lock = threading.Lock()
        self._client: Client | None = None
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="opcua-client", daemon=True)
        self._thread.start()
        self._paths: dict[str, ua.NodeId] = {}
        self._acted = False

    def _run(self, coro, timeout_s: float):
        fut = asyncio.run_coroutine_threadsafe(coro, self._loop)
        try:
            return fut.result(timeout_s)
        except TimeoutError:
            fut.cancel()
            raise

    async def _open(self) -> Client:
        s = self.security
        client = Client(self.endpoint, timeout=self.timeout_s, watchdog_intervall=max(1.0, self.timeout_s))
        client.application_uri = "urn:helicalib:client"
        if s.policy != "None":
            cert = await uacrypto.load_certificate(s.certificate)
            uri = _certificate_uri(cert)
            if uri:
                client.application_uri = uri
            await client.set_security(getattr(security_policies, f"SecurityPolicy{s.policy}"), s.certificate,
                                      s.private_key, server_certificate=s.server_certificate,
                                      mode=getattr(ua.MessageSecurityMode, s.mode))
        if s.username is not None:
            client.set_user(s.username)
            client.set_password(s.password or "")
        try:
            await asyncio.wait_for(self.request(client.connect()), self.timeout_s)
        except BaseException:
            await self._close(client)
            raise
        return client

    async def _close(self, client: Client) -> None:
        try:
            await asyncio.wait_for(client.disconnect(), 1.0)
        except Exception:  # noqa: BLE001 - the link is gone either way
            pass

    def _drop(self) -> None:
        client, self._client = self._client, None
        self._paths.clear()
        if client is not None:
            try:
                self._run(self._close(client), 2.0)
            except Exception:  # noqa: BLE001
                pass

    def call(self, what: str, job: Callable[[Client, "OpcUaLink"], object]):
        """Run ``job(client, link)`` (a coroutine function) on the loop; ``what`` names it in errors.

        The job awaits its requests through :meth:`request`. A failed attempt is retried after
        reconnecting, unless it failed after a request that acts on the plant was sent: then
        :class:`CallInDoubt` (the caller finds out whether the plant took it)."""
        with self._lock:
            if self._monotonic() < self._down_until:
                raise PlantUnreachableError(f"plant {self.endpoint}: {what} not tried: the plant did not answer "
                                            f"moments ago ({self._down_reason})")
            last = "no answer"
            for _ in range(self.attempts):
                self._acted = False
                try:
                    if self._client is None:
                        self._client = self._run(self._open(), self.timeout_s + 2.0)
                    out = self._run(job(self._client, self), 2 * self.timeout_s + 1.0)
                    self._down_until = -math.inf
                    return out
                except ua.UaStatusCodeError as exc:
                    if exc.code not in LINK_CODES:
                        if self._client is None:     # connecting was refused: a reachable plant said no
                            raise PlantError(f"plant {self.endpoint}: connecting refused: {_status_name(exc.code)}") from None
                        raise PlantError(f"plant {self.endpoint}: {what}: {_status_name(exc.code)}") from None
                    last = _status_name(exc.code)
                except (OSError, TimeoutError, asyncio.TimeoutError, ConnectionError, _LinkDown) as exc:
                    last = f"{type(exc).__name__}: {exc}".strip().rstrip(":")
                except ua.UaError as exc:          # not on the wire: e.g. a value its type cannot carry
                    raise PlantError(f"plant {self.endpoint}: {what} not sent: {exc}") from None
                self._drop()
                if self._acted:
                    raise CallInDoubt(last)
            self._down_until = self._monotonic() + self.down_s
            self._down_reason = last
            raise PlantUnreachableError(f"plant {self.endpoint}: {what} failed after {self.attempts} "
                                        f"attempt{'s' * (self.attempts > 1)} ({last})")

    async def request(self, awaitable, *, acts: bool = False):
        """Await one request on the wire. A UaError raised here (a broken message, a closed channel)
        is the link's; ``acts``: the request acts on the plant, so it is not sent a second time."""
        if acts:
            self._acted = True
        try:
            return await awaitable
        except ua.UaStatusCodeError:
            raise
        except ua.UaError as exc:
            raise _LinkDown(f"{type(exc).__name__}: {exc}") from exc

    async def node_ids(self, client: Client, refs: Sequence[str]) -> list[ua.NodeId]:
        """Node ids of map references (browse paths from Objects resolved once, then kept)."""
        out = []
        for ref in refs:
            if is_node_id(ref):
                out.append(ua.NodeId.from_string(ref))
                continue
            nid = self._paths.get(ref)
            if nid is None:
                try:
                    node = await self.request(client.nodes.objects.get_child(ref.strip("/").split("/")))
                except ua.UaStatusCodeError as exc:
                    if exc.code in LINK_CODES:
                        raise
                    raise PlantError(f"plant {self.endpoint}: browse path {ref} from Objects: "
                                     f"{_status_name(exc.code)}") from None
                nid = self._paths[ref] = node.nodeid
            out.append(nid)
        return out

    def hurry(self) -> None:
        """One attempt per call from now on and a 1 s down window (a stopping controller)."""
        self.attempts = 1
        self.down_s = min(self.down_s, 1.0)

    def close(self) -> None:
        """Disconnect, stop the event loop thread and close its loop."""
        with self._lock:
            self._drop()
        if self._loop.is_running():
            self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(5)
        if not self._thread.is_alive() and not self._loop.is_closed():
            self._loop.close()


def _certificate_uri(cert) -> str | None:
    """The application URI in a certificate's subject alternative names (what servers check)."""
    from cryptography import x509

    try:
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except x509.ExtensionNotFound:
        return None
    uris = san.get_values_for_type(x509.UniformResourceIdentifier)
    return uris[0] if uris else None
