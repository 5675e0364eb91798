"""The study service: runs sessions trial by trial, with the log as the single source of truth.

One session at a time. The operator starts (or resumes) a participant's session from the operator side (control
socket: `study.start`); the page only ever sees the current trial. A trial is:

1. presented: a two-panel scene (left and right halves of the screen; both show the reference condition's
   ground-truth visual, the same half of the garment; tactile from the two conditions' bundles, no visual
   inference) is put on the haptic device through the daemon; the page gets the layout and a fresh token;
2. shown: the page reports the trial on screen (`/api/study/shown`); that starts the response time and, for test
   trials, the time limit (warm-up is untimed). A "shown" record is logged;
3. answered: a tap with the current token is written durably (`StudyLog.record_response`, fsync'd) and only then
   acknowledged; or the limit passes and a timeout is written. Then the next trial is presented.

Everything else a participant or page can do is ignored *and logged* as an event: a second tap on an answered trial
(double tap), a tap after the time limit, a tap with an old token (stale page), a tap before the trial was shown,
a tap with no session running. Codes that the study does not accept are refused and logged (without echoing text
that is not a code). After a crash the most recent unfinished session is resumed at its first unanswered trial
(logged as a `resume` record); trials answered before the crash are never asked again.

When the log cannot be written (a full disk), nothing is acknowledged: the page is told to ask the participant to
call the researcher, the kiosk log and the `study_log` health check say why, and the trial clock stops. The timer
retries once a second; the first record that goes through again is an event saying how long the log was down, and
the current trial is presented afresh (a new token, as after a restart), all without restarting the kiosk.
"""
from __future__ import annotations

import logging
import re
import secrets
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from kiosk.contract.errors import InputError, KioskError
from kiosk.inference.scene import Panel, Scene
from kiosk.study.bundles import StudyBundles
from kiosk.study.config import CODE_RE, ParticipantError, StudyConfig
from kiosk.study.log import DuplicateResponse, StudyLog, StudyLogWriteError
from kiosk.study.records import response_payload, session_payload
from kiosk.study.schedule import SIDES, Schedule, Trial, make_schedule

if TYPE_CHECKING:
    from kiosk.service.server import Request, Response

log = logging.getLogger(__name__)

CALL_RESEARCHER = "Please call the researcher: the kiosk cannot record answers right now."
RETRY_S = 1.0           # how often a study log that refused a write is tried again
GAP_FRACTION = 0.02     # gap between the two panels, of the screen width
BAR_FRACTION = 0.16     # the button bar at the bottom, of the screen height


class StudyError(KioskError):
    """An operator request the study cannot do now (another session running, session complete, ...)."""


@dataclass(frozen=True)
class Layout:
    """Screen rectangles (x, y, w, h) in the haptic panel's pixels: two panels side by side, buttons under them."""

    screen: tuple[int, int]
    panels: dict[str, tuple[int, int, int, int]]
    buttons: dict[str, tuple[int, int, int, int]]


def study_layout(screen: tuple[int, int]) -> Layout:
    w, h = screen
    gap = max(2, round(GAP_FRACTION * w))
    bar = max(40, round(BAR_FRACTION * h))
    pw = (w - gap) // 2
    ph = h - bar
    panels = {"left": (0, 0, pw, ph), "right": (w - pw, 0, pw, ph)}
    pad = max(4, bar // 8)
    buttons = {side: (x + pad, ph + pad, pw - 2 * pad, bar - 2 * pad) for side, (x, _, pw, _) in panels.items()}
    return Layout(screen=(w, h), panels=panels, buttons=buttons)


@dataclass(frozen=True)
class Rendered:
    """What the renderer put on the device, per side: where the reference visual lies on screen."""

    placements: dict[str, dict]   # side -> {"scale", "x", "y", "size": [w, h]}
    frame: int | None = None      # the daemon's frame number, if it has one


class TrialRenderer(Protocol):
    """Puts a study scene on the haptic device (the daemon implements it; see kiosk.study.runtime)."""

    def screen(self) -> tuple[int, int]: ...
    def render(self, scene: Scene) -> Rendered: ...
    def clear(self) -> None: ...


@dataclass
class _Active:
    schedule: Schedule
    trial: Trial | None = None
    token: str | None = None
    rendered: Rendered | None = None
    shown: dict | None = None
    deadline: float | None = None
    error: str | None = None

    @property
    def key(self) -> tuple[str, int]:
        return (self.schedule.participant, self.schedule.session)


class StudyService:
    def __init__(self, config: StudyConfig, study_log: StudyLog, bundles: StudyBundles, renderer: TrialRenderer, *,
                 auto_resume: bool = True, tick_s: float = 0.05) -> None:
        self.config = config
        self.log = study_log
        self.bundles = bundles
        self.renderer = renderer
        self.identities = bundles.identities()
        self.layout = study_layout(renderer.screen())
        self._lock = threading.RLock()
        self._active: _Active | None = None
        self._finished: tuple[str, int] | None = None
        self._recent_tokens: dict[str, tuple[str, int, int, str]] = {}  # token -> (code, session, trial, outcome)
        self._stop = threading.Event()
        self._tick_s = tick_s
        self._thread: threading.Thread | None = None
        self._outage: dict | None = None   # the study log refused a write: {"error", "wall", "mono"}
        self._next_retry = 0.0
        if auto_resume:
            self._resume_after_restart()

    # -- life cycle ----------------------------------------------------------------------------------------------
    def start_timer(self) -> None:
        self._thread = threading.Thread(target=self._timer, name="vtkiosk-study-timer", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None

    def _timer(self) -> None:
        while not self._stop.wait(self._tick_s):
            try:
                if self._outage is not None:
                    self.retry_log()
                else:
                    self.check_timeout()
            except StudyLogWriteError as exc:
                with self._lock:
                    self._log_down(exc)
            except Exception:  # noqa: BLE001 - the timer must survive anything; the log says what happened
                log.exception("study timer")

    # -- a study log that refuses writes ---------------------------------------------------------------------------
    def _log_down(self, exc: StudyLogWriteError) -> None:
        """Called with the lock held: stop the trial (clock and taps) until the log takes a record again."""
        if self._outage is None:
            self._outage = {"error": str(exc), "wall": self.log.stamp()["wall"], "mono": time.monotonic()}
            log.error("study %s: %s; the page asks the participant to call the researcher, and recording resumes "
                      "by itself once the log can be written", self.config.id, exc)
            if self._active is not None:
                self._active.deadline = None
        self._next_retry = time.monotonic() + RETRY_S

    def log_error(self) -> str | None:
        """Why the study log cannot take records now (None while it can): for the health check."""
        outage = self._outage
        return None if outage is None else f"{outage['error']} (since {outage['wall'][:19]}Z)"

    def retry_log(self, *, force: bool = False) -> bool:
        """Try the study log again (at most every RETRY_S unless `force`); True once it takes a record."""
        with self._lock:
            if self._outage is None:
                return True
            if not force and time.monotonic() < self._next_retry:
                return False
            outage = self._outage
            try:
                self.log.append("event", kind="log_write_failed", detail=outage["error"][:300],
                                since=outage["wall"], down_s=round(time.monotonic() - outage["mono"], 3),
                                **self.log.stamp())
            except StudyLogWriteError as exc:
                self._log_down(exc)
                return False
            self._outage = None
            log.warning("study %s: the study log takes records again after %.0f s; recording resumes",
                        self.config.id, time.monotonic() - outage["mono"])
            if self._active is not None:
                try:
                    self._present_next()   # a fresh token and clock for the trial that was cut off
                except StudyLogWriteError as exc:
                    self._log_down(exc)
                    return False
            return True

    # -- operator ------------------------------------------------------------------------------------------------
    def start(self, participant: object, *, new_session: bool = False) -> dict:
        with self._lock:
            try:
                code = self.config.participants.check(participant)  # type: ignore[arg-type]
            except ParticipantError:
                # The operator sees the message; the log keeps only why (what was typed may be a name).
                why = ("not a code" if not (isinstance(participant, str) and CODE_RE.match(participant))
                       else "not on the list" if self.config.participants.codes else "does not match the pattern")
                self._event("participant_rejected", detail=why)
                raise
            if self._active is not None and self._active.key[0] != code:
                self._event("start_refused", code=code, detail=f"session of {self._active.key[0]} is running")
                raise StudyError(f"the session of {self._active.key[0]} is running; stop it first "
                                 "(vtkiosk study stop) or let it finish")
            latest = self.log.state.latest_session(code)
            if self._active is not None:                    # the same participant again: re-present the trial
                p, s = self._active.key
                self.log.append("resume", participant=p, session=s, reason="operator",
                                at_trial=self.log.state.sessions[(p, s)].next_trial(), **self.log.stamp())
                self._present_next()
                return self._summary()
            if latest is not None and latest.next_trial() is not None and not new_session:
                schedule = Schedule.from_json(latest.started["schedule"])
                self._check_resumable(latest.started, schedule)
                self._active = _Active(schedule)
                self.log.append("resume", participant=code, session=latest.session, reason="operator",
                                at_trial=latest.next_trial(), **self.log.stamp())
            else:
                if latest is not None and latest.next_trial() is None and not new_session:
                    raise StudyError(f"participant {code} has completed session {latest.session}; use --new-session "
                                     "to run another")
                if latest is not None and latest.next_trial() is not None:   # the operator gives it up
                    self.log.append("end", participant=code, session=latest.session, reason="abandoned",
                                    at_trial=latest.next_trial(), **self.log.stamp())
                session = 1 if latest is None else latest.session + 1
                schedule = make_schedule(self.config, code, session)
                self.log.append("session", **session_payload(self.config, schedule, self.identities,
                                                             software=self.log.software, stamp=self.log.stamp()))
                self._active = _Active(schedule)
            self._finished = None
            self._present_next()
            return self._summary()

    def stop(self) -> dict:
        with self._lock:
            if self._active is None:
                return {"stopped": None}
            p, s = self._active.key
            self.log.append("end", participant=p, session=s, reason="stopped", **self.log.stamp())
            self._active = None
            self._safe_clear()
            return {"stopped": {"participant": p, "session": s}}

    def status(self) -> dict:
        with self._lock:
            out = {"study_id": self.config.id, "log": str(self.log.path), "sessions": len(self.log.state.sessions),
                   "responses": len(self.log.state.responses()), "active": None, "log_error": self.log_error()}
            if self._active is not None:
                out["active"] = self._summary()
            if self._finished is not None:
                out["finished"] = {"participant": self._finished[0], "session": self._finished[1]}
            return out

    def _summary(self) -> dict:
        a = self._active
        assert a is not None
        s = self.log.state.sessions[a.key]
        t = a.trial
        return {"participant": a.key[0], "session": a.key[1], "trials": s.n_trials, "answered": len(s.responses),
                "trial": None if t is None else t.index, "garment": None if t is None else t.garment,
                "block": None if t is None else t.block, "error": a.error,
                "put_garment_on_table": None if t is None else t.garment}

    # -- trials --------------------------------------------------------------------------------------------------
    def _resume_after_restart(self) -> None:
        candidates = [s for s in self.log.state.sessions.values() if not s.ended and s.next_trial() is not None]
        if not candidates:
            return
        s = max(candidates, key=lambda s: max([s.started["seq"]] + [r["seq"] for r in s.responses.values()]))
        schedule = Schedule.from_json(s.started["schedule"])
        try:
            self._check_resumable(s.started, schedule)
        except StudyError as exc:
            log.warning("not resuming %s session %s: %s", s.participant, s.session, exc)
            self._event("resume_impossible", participant=s.participant, session=s.session, detail=str(exc))
            return
        self._active = _Active(schedule)
        try:
            self.log.append("resume", participant=s.participant, session=s.session, reason="restart",
                            at_trial=s.next_trial(), **self.log.stamp())
        except StudyLogWriteError as exc:   # started on a full disk: wait for space like a running study does
            self._log_down(exc)
            return
        self._present_next()

    def _check_resumable(self, started: dict, schedule: Schedule) -> None:
        """A stored schedule can only continue with the bundles it was made for (the config may have changed)."""
        missing = sorted({f"{c}:{t.garment}" for t in schedule.trials for c in (t.left, t.right)
                          if (c, t.garment) not in self.bundles.items})
        if missing:
            raise StudyError(f"session {schedule.session} of {schedule.participant} was scheduled with bundle(s) "
                             f"this study config no longer has: {', '.join(missing)}; restore them or start a new "
                             "session (--new-session)")
        if started.get("config_sha256") != self.config.source_sha256:
            self._event("config_changed", participant=schedule.participant, session=schedule.session,
                        detail="the study config differs from the one this session started with")

    def _present_next(self) -> None:
        a = self._active
        assert a is not None
        state = self.log.state.sessions[a.key]
        index = state.next_trial()
        if index is None:
            self.log.append("end", participant=a.key[0], session=a.key[1], reason="complete", **self.log.stamp())
            self._finished = a.key
            self._active = None
            self._safe_clear()
            return
        trial = a.schedule.trials[index]
        a.trial, a.token, a.shown, a.deadline, a.error, a.rendered = trial, None, None, None, None, None
        try:
            a.rendered = self.renderer.render(self.scene_for(trial))
        except Exception as exc:  # noqa: BLE001 - a failed rendering blocks the trial; the operator is told
            a.error = f"the haptic rendering failed: {exc}"
            log.error("study trial %s of %s: %s", trial.index, a.key[0], a.error)
            self._event("render_failed", participant=a.key[0], session=a.key[1], trial=trial.index,
                        detail=str(exc)[:300])
            return
        a.token = f"{a.key[1]}-{trial.index}-{secrets.token_hex(6)}"

    def scene_for(self, trial: Trial) -> Scene:
        """Both halves: reference visual (no visual inference), tactile from each side's condition, same half."""
        panels = tuple(Panel(id=side, rect=self.layout.panels[side],
                             bundle=self.bundles.get(trial.condition_on(side), trial.garment).key,
                             visual="reference", tactile="model", sketch="reference", half=trial.half)
                       for side in SIDES)
        return Scene(panels=panels, screen=self.layout.screen)

    def page_state(self) -> dict:
        with self._lock:
            if self._outage is not None:
                return {"state": "call_researcher", "notice": CALL_RESEARCHER}
            a = self._active
            if a is None:
                if self._finished is not None:
                    return {"state": "done", "notice": "Thank you! This session is complete."}
                return {"state": "idle", "notice": "Please wait for the experimenter."}
            if a.error is not None or a.token is None or a.trial is None or a.rendered is None:
                return {"state": "unavailable", "notice": "Please wait: the experimenter has been notified."}
            t = a.trial
            tests = [x for x in a.schedule.trials if x.block == "test"]
            ident = self.identities[self.config.reference][t.garment]["manifest_sha256"][:12]
            return {"state": "trial", "trial": {
                "token": a.token, "index": t.index, "block": t.block, "timed": t.timed,
                "number": (tests.index(t) + 1) if t.timed else None, "of": len(tests),
                "time_limit_s": self.config.time_limit_s if t.timed else None,
                "time_left_s": self._time_left(a), "question": self.config.question,
                "screen": list(self.layout.screen), "visual": f"/api/study/visual/{t.garment}.png?v={ident}",
                "panels": [{"side": side, "rect": list(self.layout.panels[side]),
                            "placement": a.rendered.placements[side]} for side in SIDES],
                "buttons": [{"side": side, "rect": list(self.layout.buttons[side])} for side in SIDES]}}

    def _time_left(self, a: _Active) -> float | None:
        if a.deadline is None:
            return None
        return max(0.0, a.deadline - time.monotonic())

    def shown(self, token: object) -> dict:
        with self._lock:
            a = self._active
            if a is None or token != a.token or a.trial is None:
                return {"ok": False, "ignored": "not the current trial"}
            if a.shown is None:
                a.shown = self.log.append("shown", participant=a.key[0], session=a.key[1], trial=a.trial.index,
                                          token=a.token, **self.log.stamp())
                if a.trial.timed:
                    a.deadline = a.shown["mono"] + self.config.time_limit_s
            return {"ok": True, "time_left_s": self._time_left(a)}

    def choose(self, token: object, side: object) -> dict:
        """A participant's tap. Returns {"recorded": True, ...} only after the response is durable."""
        if side not in SIDES:
            raise InputError("side must be 'left' or 'right'")
        if not isinstance(token, str) or not 0 < len(token) <= 64:
            raise InputError("token must be the trial's token (a short string)")
        with self._lock:
            a = self._active
            if a is None or token != a.token:
                if token in self._recent_tokens:
                    p, s, i, outcome = self._recent_tokens[token]
                    kind = "tap_after_timeout" if outcome == "timeout" else "double_tap"
                    return self._ignore(kind, participant=p, session=s, trial=i, side=side)
                if a is None:
                    return self._ignore("tap_without_session", token=token, side=side)
                return self._ignore("stale_tap", participant=a.key[0], session=a.key[1], token=token, side=side)
            assert a.trial is not None
            if a.shown is None:
                return self._ignore("tap_before_shown", participant=a.key[0], session=a.key[1], trial=a.trial.index,
                                    side=side)
            now = self.log.stamp()
            if a.deadline is not None and now["mono"] >= a.deadline:
                trial, late = a.trial.index, round(now["mono"] - a.deadline, 4)
                self._record_timeout(a)
                return self._ignore("tap_after_timeout", participant=a.key[0], session=a.key[1], trial=trial,
                                    side=side, late_s=late)
            try:
                rec = self.log.record_response(**response_payload(
                    a.schedule, a.trial, choice=side, timeout=False, rt_s=now["mono"] - a.shown["mono"],
                    time_limit_s=self.config.time_limit_s if a.trial.timed else None, bundles=self.identities,
                    software=self.log.software, shown=a.shown, stamp=now))
            except DuplicateResponse:
                return self._ignore("double_tap", participant=a.key[0], session=a.key[1], trial=a.trial.index,
                                    side=side)
            self._remember(a.token, a.key, a.trial.index, "answered")
            try:
                self._present_next()
            except StudyLogWriteError as exc:   # the choice is durable; only what follows it waits for space
                self._log_down(exc)
            return {"recorded": True, "trial": rec["trial"], "side": side, "seq": rec["seq"]}

    def check_timeout(self) -> None:
        with self._lock:
            a = self._active
            if self._outage is None and a is not None and a.deadline is not None and time.monotonic() >= a.deadline:
                self._record_timeout(a)

    def _record_timeout(self, a: _Active) -> None:
        assert a.trial is not None and a.shown is not None
        try:
            self.log.record_response(**response_payload(
                a.schedule, a.trial, choice=None, timeout=True, rt_s=None, time_limit_s=self.config.time_limit_s,
                bundles=self.identities, software=self.log.software, shown=a.shown, stamp=self.log.stamp()))
        except DuplicateResponse:
            pass
        if a.token is not None:
            self._remember(a.token, a.key, a.trial.index, "timeout")
        self._present_next()

    def _remember(self, token: str, key: tuple[str, int], index: int, outcome: str) -> None:
        self._recent_tokens[token] = (key[0], key[1], index, outcome)
        while len(self._recent_tokens) > 64:
            self._recent_tokens.pop(next(iter(self._recent_tokens)))

    def _ignore(self, kind: str, **detail: object) -> dict:
        self._event(kind, **detail)
        return {"recorded": False, "ignored": kind}

    def _event(self, kind: str, **detail: object) -> None:
        self.log.append("event", kind=kind, **{k: v for k, v in detail.items() if v is not None}, **self.log.stamp())

    def _safe_clear(self) -> None:
        try:
            self.renderer.clear()
        except Exception as exc:  # noqa: BLE001 - blanking is best effort; the device blanks itself when idle
            log.warning("clearing the haptic device after a session: %s", exc)

    # -- the page's API and the operator's control ops (mounted by kiosk.study.runtime) ---------------------------
    def http_get(self, req: "Request") -> "Response":
        from kiosk.service.server import Response

        if req.path == "/api/study/trial":
            return Response.json(self.page_state())
        m = _VISUAL_RE.fullmatch(req.path)
        if m and m.group(1) in self.config.garments:
            path = self.bundles.visual_file(m.group(1))
            ctype = _IMAGE_TYPES.get(path.suffix.lower(), "application/octet-stream")
            return Response(200, path.read_bytes(), ctype, {"Cache-Control": "private, max-age=3600"})
        return Response.error(404, f"nothing at {req.path}")

    def http_post(self, req: "Request") -> "Response":
        from kiosk.service.server import Response

        body = req.json()
        if not isinstance(body, dict):
            raise InputError("the request body must be a JSON object")
        if req.path not in ("/api/study/shown", "/api/study/choice"):
            return Response.error(404, f"nothing at {req.path}")
        _only(body, {"token"} if req.path == "/api/study/shown" else {"token", "side"})
        unavailable = Response.json({"recorded": False, "error": "the study log cannot be written; nothing was "
                                     "recorded", "notice": CALL_RESEARCHER}, 503)
        if self._outage is not None:
            return unavailable
        try:
            if req.path == "/api/study/shown":
                return Response.json(self.shown(body.get("token")))
            return Response.json(self.choose(body.get("token"), body.get("side")))
        except StudyLogWriteError as exc:
            with self._lock:
                self._log_down(exc)
            return unavailable

    def control(self, request: dict) -> dict:
        """Control-socket ops: study.start {participant, new_session}, study.status, study.stop."""
        op = request.get("op")
        try:
            if op == "study.start":
                return {"ok": True, **self.start(request.get("participant"),
                                                 new_session=bool(request.get("new_session", False)))}
            if op == "study.status":
                return {"ok": True, **self.status()}
            if op == "study.stop":
                return {"ok": True, **self.stop()}
        except StudyLogWriteError as exc:
            with self._lock:
                self._log_down(exc)
            return {"ok": False, "error": str(exc)}
        except KioskError as exc:
            return {"ok": False, "error": str(exc)}
        return {"ok": False, "error": f"unknown study op {op!r} (study.start, study.status, study.stop)"}


_VISUAL_RE = re.compile(r"/api/study/visual/([a-z0-9][a-z0-9._-]{0,63})\.png")
_IMAGE_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".webp": "image/webp"}


def _only(body: dict, allowed: set[str]) -> None:
    extra = sorted(str(k) for k in body if k not in allowed)
    if extra:
        raise InputError(f"unknown field(s): {', '.join(extra)}")
