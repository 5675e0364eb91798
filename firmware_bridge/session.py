"""Reliable exchanges over a transport: sequence numbers, ACK/NACK matching, timeouts, bounded retransmission.

`request()` is stop-and-wait for control messages (HELLO, BEGIN, COMMIT, ...). `send_tiles()` keeps up to `window`
TILE messages in flight, so the link's turnaround latency is paid about once per window instead of once per tile;
each tile is retransmitted with the same sequence number when its ACK is late or a NACK says it arrived damaged,
at most `max_retries` times. Replies whose sequence number or type does not match an outstanding request
(duplicates, late or reordered replies) are counted and ignored. Every loop is bounded by retries and timeouts.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass

from . import protocol as P
from .errors import LinkError, ProtocolError


class LinkTimeout(LinkError):
    """No matching reply after every retry (the transport itself did not fail)."""


class Rejected(Exception):
    """The device NACKed a tile for a reason a retransmission cannot fix (internal to the display)."""

    def __init__(self, nack: P.Nack) -> None:
        super().__init__(f"{P.MsgType(nack.acked_type).name} rejected: {P.NackCode(nack.code).name}")
        self.nack = nack


RETRANSMIT_NACKS = {P.NackCode.TILE_CRC, P.NackCode.DECODE}


@dataclass
class _InFlight:
    msg: P.Tile
    data: bytes
    deadline: float
    attempts: int


class Session:
    def __init__(self, transport, config) -> None:
        self.transport = transport
        self.config = config
        self.clock = transport.clock
        self._seq = 0
        self.stats: Counter[str] = Counter()

    def next_seq(self) -> int:
        self._seq = (self._seq + 1) & 0xFFFF
        return self._seq

    @staticmethod
    def matches(req: P.Message, reply: P.Message) -> bool:
        if reply.seq != req.seq:
            return False
        if isinstance(reply, P.Nack):
            return reply.acked_type == req.TYPE
        if isinstance(req, P.Hello):
            return isinstance(reply, P.Info)
        if isinstance(req, P.Heartbeat):
            return isinstance(reply, P.Status) and reply.counter == req.counter
        return isinstance(reply, P.Ack) and reply.acked_type == req.TYPE

    def _receive(self, timeout_s: float) -> P.Message | None:
        raw = self.transport.recv(timeout_s)
        if raw is None:
            return None
        try:
            return P.parse(raw)
        except ProtocolError:
            self.stats["bad_replies"] += 1
            return None

    def request(self, build: Callable[[int], P.Message], timeout_s: float | None = None,
                retries: int | None = None) -> P.Message:
        """Send build(seq) until a matching ACK/NACK/INFO/STATUS arrives. Raises LinkTimeout or LinkError."""
        msg = build(self.next_seq())
        data = P.encode(msg)
        timeout_s = self.config.ack_timeout_s if timeout_s is None else timeout_s
        retries = self.config.max_retries if retries is None else retries
        for attempt in range(retries + 1):
            if attempt:
                self.stats["retransmits"] += 1
            self.transport.send(data)
            deadline = self.clock.now() + timeout_s
            for _ in range(256):  # bounded: at most this many unrelated replies per attempt
                remaining = deadline - self.clock.now()
                if remaining <= 0:
                    break
                reply = self._receive(remaining)
                if reply is None:
                    if self.clock.now() >= deadline:
                        break
                    continue
                if self.matches(msg, reply):
                    if isinstance(reply, P.Nack):
                        self.stats["nacks"] += 1
                    return reply
                self.stats["stale_replies"] += 1
            self.stats["timeouts"] += 1
        raise LinkTimeout(f"no answer to {msg.TYPE.name} after {retries + 1} tries of "
                          f"{timeout_s * 1000:.0f} ms; bridge busy or link down")

    def send_tiles(self, tiles: list[Callable[[int], P.Tile]]) -> None:
        """Deliver every tile (each built with its sequence number) with a sliding window.

        Raises LinkTimeout when one tile exhausts its retries, Rejected on a NACK a retransmission cannot fix.
        """
        cfg = self.config
        todo = list(reversed(tiles))
        inflight: dict[int, _InFlight] = {}
        budget = (len(tiles) + 1) * (cfg.max_retries + 2) * 4 + 64
        for _ in range(budget):
            if not todo and not inflight:
                return
            while todo and len(inflight) < cfg.window:
                msg = todo.pop()(self.next_seq())
                data = P.encode(msg)
                self.transport.send(data)
                inflight[msg.seq] = _InFlight(msg, data, self.clock.now() + cfg.ack_timeout_s, 1)
            wait = min(f.deadline for f in inflight.values()) - self.clock.now()
            raw = self.transport.recv(max(wait, 0.0))
            if raw is not None:  # replies first: a deadline only counts once nothing is waiting to be read
                try:
                    reply = P.parse(raw)
                except ProtocolError:
                    self.stats["bad_replies"] += 1
                    continue
                f = inflight.get(reply.seq)
                if f is None or not self.matches(f.msg, reply):
                    self.stats["stale_replies"] += 1
                elif isinstance(reply, P.Ack):
                    del inflight[reply.seq]
                else:
                    self.stats["nacks"] += 1
                    if reply.code not in RETRANSMIT_NACKS:
                        raise Rejected(reply)
                    f.deadline = float("-inf")  # damaged on the way: retransmit at once
                if f is None or f.deadline != float("-inf"):
                    continue
            now = self.clock.now()
            for f in inflight.values():
                if f.deadline <= now:
                    if f.attempts > cfg.max_retries:
                        raise LinkTimeout(f"tile ({f.msg.tx}, {f.msg.ty}) of frame {f.msg.frame_id} not acknowledged "
                                          f"after {f.attempts} tries")
                    f.attempts += 1
                    self.stats["retransmits"] += 1
                    self.transport.send(f.data)
                    f.deadline = self.clock.now() + cfg.ack_timeout_s
        raise LinkTimeout(f"tile upload did not finish within its retry budget ({len(inflight)} tiles unacknowledged)")
