"""The study service: runs sessions stage by stage, with the log as the single source of truth.

One session at a time. The operator starts (or resumes) a participant's session from the operator side (control
socket: `study.start`); the page only ever sees the current stage. A session runs:

1. consent (when the config has a consent text): the participant agrees or not; the log keeps the answer as a
   boolean with the text's version and SHA-256. No trial is presented before an agreement is on disk;
2. demographics (optional, declared in the config; every field may be left unanswered);
3. familiarisation (haptic studies, optional): generated textures (uniform levels, gratings, bumps, ridges) at
   their physical size, untimed; logged, never analysed, and only the operator can skip it (`study.skip`);
4. trials. Between trials the participant sees "please wait" and the operator sees which garment to put on the
   table; the operator releases the next trial (`study.next`, the operator page, or a key on the kiosk's keyboard)
   unless the config says `release: none`. A released trial is presented: a two-panel scene goes to the device
   through the daemon and the page gets the layout and a fresh token. The response time and (test trials) the time
   limit start when the page reports the trial on screen (`/api/study/shown`); a reloaded page reports it again
   and the response time counts from that page. A tap with the current token is written durably and only then
   acknowledged; a test trial not answered in time is written as a timeout and the participant is told so.

Everything else a participant or page can do is ignored *and logged* as an event: a second tap on an answered trial
(double tap), a tap after the time limit, a tap with an old token (stale page), a tap before the trial was shown,
a tap with no session running. Codes that the study does not accept are refused and logged (without echoing text
that is not a code). After a crash the most recent unfinished session is resumed at its first unanswered trial
(logged as a `resume` record); trials answered before the crash are never asked again. A withdrawn participant's
session ends at once; the report leaves them out and the log keeps every record.

When the log cannot be written (a full disk), nothing is acknowledged: the page is told to ask the participant to
call the researcher, the kiosk log and the `study_log` health check say why, and the trial clock stops. The timer
retries once a second; the first record that goes through again is an event saying how long the log was down, and
the current stage is presented afresh (a new token, as after a restart), all without restarting the kiosk.
"""
from __future__ import annotations

import logging
import re
import secrets
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from kiosk.contract.errors import InputError, KioskError
from kiosk.inference.scene import Panel, Scene
from kiosk.study.bundles import StudyBundles
from kiosk.study.config import CODE_RE, ParticipantError, StudyConfig
from kiosk.study.familiarise import texture_pixels
from kiosk.study.log import DuplicateResponse, StudyLog, StudyLogWriteError
from kiosk.study.records import response_payload, session_payload
from kiosk.study.schedule import SIDES, Schedule, Trial, make_schedule

if TYPE_CHECKING:
    from kiosk.service.server import Request, Response

log = logging.getLogger(__name__)

CALL_RESEARCHER = "Please call the researcher: the kiosk cannot record answers right now."
RETRY_S = 1.0             # how often a study log that refused a write is tried again
GAP_FRACTION = 0.02       # gap between the two panels, of the screen width
BAR_FRACTION = 0.16       # the button bar at the bottom, of the screen height
QUESTION_FRACTION = 0.12  # the question band at the top, of the screen height (the question never covers a panel)


class StudyError(KioskError):
    """An operator request the study cannot do now (another session running, session complete, ...)."""


@dataclass(frozen=True)
class Layout:
    """Screen rectangles (x, y, w, h) in the haptic panel's pixels: the question band on top, two panels side by
    side under it, buttons under them."""

    screen: tuple[int, int]
    panels: dict[str, tuple[int, int, int, int]]
    buttons: dict[str, tuple[int, int, int, int]]
    question: tuple[int, int, int, int] = (0, 0, 0, 0)

    @property
    def stage(self) -> tuple[int, int, int, int]:
        """Everything between the question band and the buttons (where familiarisation textures lie)."""
        w, _ = self.screen
        x, y, _, h = self.panels["left"]
        return (0, y, w, h)


def study_layout(screen: tuple[int, int]) -> Layout:
    w, h = screen
    gap = max(2, round(GAP_FRACTION * w))
    bar = max(40, round(BAR_FRACTION * h))
    top = max(40, round(QUESTION_FRACTION * h))
    pw = (w - gap) // 2
    ph = h - bar - top
    panels = {"left": (0, top, pw, ph), "right": (w - pw, top, pw, ph)}
    pad = max(4, bar // 8)
    buttons = {side: (x + pad, top + ph + pad, pw - 2 * pad, bar - 2 * pad) for side, (x, _, pw, _) in panels.items()}
    return Layout(screen=(w, h), panels=panels, buttons=buttons, question=(0, 0, w, top))


@dataclass(frozen=True)
class Rendered:
    """What the renderer put on screen, per side: where the reference visual lies (haptic study), or the model's
    visual output as PNG and the screen rectangle it fills (visual study)."""

    placements: dict[str, dict]   # side -> {"scale", "x", "y", "size": [w, h]} or {"rect": [x, y, w, h]}
    frame: int | None = None      # the daemon's frame number, if it has one
    images: dict[str, bytes] = field(default_factory=dict)


class TrialRenderer(Protocol):
    """Puts a study scene on the haptic device (the daemon implements it; see kiosk.study.runtime)."""

    def screen(self) -> tuple[int, int]: ...
    def render(self, scene: Scene) -> Rendered: ...
    def clear(self) -> None: ...
    def friction(self, rect: tuple[int, int, int, int], pixels: np.ndarray) -> None: ...


@dataclass
class _Active:
    schedule: Schedule
    stage: str = "trial"            # consent | demographics | familiarisation | wait | trial | timeout
    trial: Trial | None = None      # the trial on screen, waiting for release, or just timed out
    token: str | None = None
    rendered: Rendered | None = None
    shown: dict | None = None       # the latest 'shown' record: the response time counts from it
    page: str | None = None         # the page instance that reported it
    deadline: float | None = None
    error: str | None = None
    step: int = 0                   # familiarisation texture on screen
    texture_png: bytes | None = None
    notice_until: float | None = None
    released_once: bool = False     # the first trial after a start or resume always waits for the operator

    @property
    def key(self) -> tuple[str, int]:
        return (self.schedule.participant, self.schedule.session)


NOTICES = {
    "idle": "Please wait for the experimenter.",
    "wait": "Please wait: the experimenter is preparing the next pair.",
    "timeout": "Time is up for this pair, so no answer was recorded. The next pair follows.",
    "done": "Thank you! This session is complete.",
    "no_consent": "Thank you. The study does not go on without your consent; please tell the experimenter.",
    "withdrawn": "Thank you. This session has ended.",
    "unavailable": "Please wait: the experimenter has been notified.",
}


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
        self._finish_notice = NOTICES["done"]
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
                    self._advance()   # a fresh token and clock for the stage that was cut off
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
            if code in self.log.state.withdrawn:
                self._event("start_refused", code=code, detail="withdrawn")
                raise StudyError(f"participant {code} has withdrawn from the study; their records stay in the log "
                                 "but no new session starts")
            if self._active is not None and self._active.key[0] != code:
                self._event("start_refused", code=code, detail=f"session of {self._active.key[0]} is running")
                raise StudyError(f"the session of {self._active.key[0]} is running; stop it first "
                                 "(vtkiosk study stop) or let it finish")
            latest = self.log.state.latest_session(code)
            if self._active is not None:                    # the same participant again: re-present the stage
                p, s = self._active.key
                self.log.append("resume", participant=p, session=s, reason="operator",
                                at_trial=self.log.state.sessions[(p, s)].next_trial(), **self.log.stamp())
                self._active = _Active(self._active.schedule)
                self._advance()
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
            if self.config.kind == "visual":
                self._safe_clear()          # the haptic layer is off for the whole session
            self._advance()
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

    def release(self, *, by: str = "operator") -> dict:
        """The operator lets the waiting trial appear (its clock starts once the page shows it)."""
        with self._lock:
            a = self._active
            if a is None:
                raise StudyError("no session is running")
            if a.stage != "wait" or a.trial is None:
                raise StudyError(f"nothing is waiting for release (the session is at its {a.stage} stage)")
            self.log.append("release", participant=a.key[0], session=a.key[1], trial=a.trial.index, by=by,
                            **self.log.stamp())
            a.released_once = True
            self._present(a.trial)
            return self._summary()

    def skip_familiarisation(self) -> dict:
        """Only the operator can skip the familiarisation stage (the participant's page has no way to)."""
        with self._lock:
            a = self._active
            if a is None:
                raise StudyError("no session is running")
            s = self.log.state.sessions[a.key]
            if self.config.familiarisation is None or s.familiarised:
                raise StudyError("this session has no familiarisation stage left to skip")
            self.log.append("familiarisation", participant=a.key[0], session=a.key[1], step=a.step,
                            action="skipped", by="operator", **self.log.stamp())
            self._advance()
            return self._summary()

    def withdraw(self, participant: object) -> dict:
        """Mark a participant withdrawn: their session (if running) ends, the report leaves them out; nothing is
        deleted."""
        with self._lock:
            code = self.config.participants.check(participant)  # type: ignore[arg-type]
            sessions = [k for k in self.log.state.sessions if k[0] == code]
            if not sessions and (self._active is None or self._active.key[0] != code):
                raise StudyError(f"participant {code} has no session in this study's log")
            already = code in self.log.state.withdrawn
            if not already:
                self.log.append("withdraw", participant=code, reason="operator", **self.log.stamp())
            if self._active is not None and self._active.key[0] == code:
                p, s = self._active.key
                self.log.append("end", participant=p, session=s, reason="withdrawn", **self.log.stamp())
                self._finish(self._active.key, NOTICES["withdrawn"])
            return {"withdrawn": code, "sessions": len(sessions), "already": already}

    def status(self, *, counts: bool = False) -> dict:
        with self._lock:
            out = {"study_id": self.config.id, "kind": self.config.kind, "log": str(self.log.path),
                   "sessions": len(self.log.state.sessions), "responses": len(self.log.state.responses()),
                   "withdrawn": sorted(self.log.state.withdrawn), "active": None, "counts": None,
                   "log_error": self.log_error(),
                   "participants_done": sorted({p for (p, _), s in self.log.state.sessions.items()
                                                if s.next_trial() is None and p not in self.log.state.withdrawn})}
            if self._active is not None:
                out["active"] = self._summary()
            if self._finished is not None:
                out["finished"] = {"participant": self._finished[0], "session": self._finished[1]}
            if counts:
                out["counts"] = self.counts()
            return out

    def counts(self) -> list[dict]:
        """Running preference counts per comparison (answered test trials of participants not withdrawn)."""
        rows: dict[str, list[int]] = {c: [0, 0, 0] for c in self.config.comparisons}
        for r in self.log.state.responses():
            if r["block"] != "test" or r["participant"] in self.log.state.withdrawn:
                continue
            c = rows.setdefault(r["comparison"], [0, 0, 0])
            if r["timeout"]:
                c[2] += 1
            else:
                c[0] += int(bool(r["chose_reference"]))
                c[1] += 1
        return [{"comparison": c, "reference": self.config.reference, "prefer_reference": k, "n": n, "timeouts": t}
                for c, (k, n, t) in rows.items()]

    def _summary(self) -> dict:
        a = self._active
        assert a is not None
        s = self.log.state.sessions[a.key]
        t = a.trial
        tests = [x for x in a.schedule.trials if x.block == "test"]
        fam = self.config.familiarisation
        return {"participant": a.key[0], "session": a.key[1], "stage": a.stage, "trials": s.n_trials,
                "answered": len(s.responses), "test_answered": sum(1 for r in s.responses.values()
                                                                   if r["block"] == "test"),
                "test_trials": len(tests), "trial": None if t is None else t.index,
                "garment": None if t is None else t.garment, "block": None if t is None else t.block,
                "comparison": None if t is None else t.comparison, "error": a.error,
                "waiting_for_release": a.stage == "wait",
                "put_garment_on_table": None if t is None else t.garment,
                "time_left_s": self._time_left(a) if a.stage == "trial" else None,
                "familiarisation": None if fam is None or a.stage != "familiarisation" else
                {"step": a.step + 1, "of": len(fam.textures), "texture": fam.textures[a.step].label}}

    # -- stages --------------------------------------------------------------------------------------------------
    def _resume_after_restart(self) -> None:
        candidates = [s for s in self.log.state.sessions.values() if not s.ended and s.next_trial() is not None
                      and s.participant not in self.log.state.withdrawn]
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
        self._advance()

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

    def _new_token(self, a: _Active, what: str) -> str:
        return f"{a.key[1]}-{what}-{secrets.token_hex(6)}"

    def _advance(self) -> None:
        """Move the session to its next stage: consent, demographics, familiarisation, then trial by trial."""
        a = self._active
        assert a is not None
        s = self.log.state.sessions[a.key]
        a.trial, a.token, a.shown, a.page, a.deadline, a.error, a.rendered = None, None, None, None, None, None, None
        a.notice_until = None
        if self.config.consent is not None and not s.consented:
            a.stage, a.token = "consent", self._new_token(a, "consent")
            return
        if self.config.demographics is not None and s.demographics is None:
            a.stage, a.token = "demographics", self._new_token(a, "about")
            return
        fam = self.config.familiarisation
        if fam is not None and not s.familiarised:
            step = s.familiarisation_step()
            if step < len(fam.textures):
                self._present_texture(step)
                return
            self.log.append("familiarisation", participant=a.key[0], session=a.key[1], step=step,
                            action="complete", **self.log.stamp())
        index = s.next_trial()
        if index is None:
            self.log.append("end", participant=a.key[0], session=a.key[1], reason="complete", **self.log.stamp())
            self._finish(a.key, NOTICES["done"])
            return
        trial = a.schedule.trials[index]
        if self._needs_release(a, trial):
            a.stage, a.trial = "wait", trial
            if self.config.kind == "haptic":
                self._safe_clear()      # nothing to feel while the garment on the table is swapped
            return
        self._present(trial)

    def _needs_release(self, a: _Active, trial: Trial) -> bool:
        if self.config.release == "none":
            return False
        if self.config.release == "each_trial" or not a.released_once or trial.index == 0:
            return True
        return a.schedule.trials[trial.index - 1].garment != trial.garment

    def _finish(self, key: tuple[str, int], notice: str) -> None:
        self._finished = key
        self._finish_notice = notice
        self._active = None
        self._safe_clear()

    def _present_texture(self, step: int) -> None:
        a = self._active
        assert a is not None and self.config.familiarisation is not None
        fam = self.config.familiarisation
        tex = fam.textures[step]
        a.stage, a.step, a.token = "familiarisation", step, self._new_token(a, f"f{step}")
        rect = self.layout.stage
        try:
            pixels = texture_pixels(tex, (rect[2], rect[3]), self.layout.screen, fam.screen_mm)
            self.renderer.friction(rect, pixels)
            a.texture_png = _png(pixels)
        except Exception as exc:  # noqa: BLE001 - the operator is told; the participant sees "please wait"
            a.error = f"the familiarisation texture could not be shown: {exc}"
            log.error("study familiarisation of %s: %s", a.key[0], a.error)
            self._event("render_failed", participant=a.key[0], session=a.key[1], detail=str(exc)[:300])
            return
        self.log.append("familiarisation", participant=a.key[0], session=a.key[1], step=step, action="shown",
                        texture={k: v for k, v in vars(tex).items() if v is not None}, label=tex.label,
                        **self.log.stamp())

    def _present(self, trial: Trial) -> None:
        a = self._active
        assert a is not None
        a.stage, a.trial = "trial", trial
        a.token, a.shown, a.page, a.deadline, a.error, a.rendered = None, None, None, None, None, None
        try:
            a.rendered = self.renderer.render(self.scene_for(trial))
        except Exception as exc:  # noqa: BLE001 - a failed rendering blocks the trial; the operator is told
            a.error = f"the rendering failed: {exc}"
            log.error("study trial %s of %s: %s", trial.index, a.key[0], a.error)
            self._event("render_failed", participant=a.key[0], session=a.key[1], trial=trial.index,
                        detail=str(exc)[:300])
            return
        a.token = f"{a.key[1]}-{trial.index}-{secrets.token_hex(6)}"

    def scene_for(self, trial: Trial) -> Scene:
        return trial_scene(self.config, self.bundles, self.layout, trial)

    def _time_limit(self, trial: Trial) -> float | None:
        return self.config.time_limit_s if trial.timed else None

    def page_state(self) -> dict:
        with self._lock:
            if self._outage is not None:
                return {"state": "call_researcher", "notice": CALL_RESEARCHER}
            a = self._active
            if a is None:
                if self._finished is not None:
                    return {"state": "done", "notice": self._finish_notice}
                return {"state": "idle", "notice": NOTICES["idle"]}
            if a.error is not None:
                return {"state": "unavailable", "notice": NOTICES["unavailable"]}
            base = {"kind": self.config.kind, "question": self.config.question}
            if a.stage == "consent":
                c = self.config.consent
                assert c is not None
                return {"state": "consent", "token": a.token, "consent": {"version": c.version, "text": c.text},
                        **base}
            if a.stage == "demographics":
                return {"state": "demographics", "token": a.token, "fields": {
                    k: list(v) for k, v in (self.config.demographics or {}).items()}, **base}
            if a.stage == "familiarisation":
                fam = self.config.familiarisation
                assert fam is not None
                return {"state": "familiarisation", "token": a.token, "step": a.step + 1, "of": len(fam.textures),
                        "label": fam.textures[a.step].label, "instructions": self.config.instructions,
                        "image": f"/api/study/texture/{a.token}.png", "screen": list(self.layout.screen),
                        "rect": list(self.layout.stage), **base}
            if a.stage == "wait":
                assert a.trial is not None
                first = not self.log.state.sessions[a.key].responses
                return {"state": "wait", "notice": NOTICES["wait"],
                        "instructions": self.config.instructions if first else None, **base}
            if a.stage == "timeout":
                return {"state": "timeout", "notice": NOTICES["timeout"], **base}
            if a.token is None or a.trial is None or a.rendered is None:
                return {"state": "unavailable", "notice": NOTICES["unavailable"]}
            t = a.trial
            tests = [x for x in a.schedule.trials if x.block == "test"]
            trial = {
                "token": a.token, "index": t.index, "block": t.block, "timed": self._time_limit(t) is not None,
                "number": (tests.index(t) + 1) if t.block == "test" else None, "of": len(tests),
                "time_limit_s": self._time_limit(t), "time_left_s": self._time_left(a),
                "question": self.config.question, "kind": self.config.kind,
                "instructions": _practice_hint(self._time_limit(t) is None) if t.block == "warmup" else None,
                "screen": list(self.layout.screen), "question_rect": list(self.layout.question),
                "panels": [{"side": side, "rect": list(self.layout.panels[side]),
                            "placement": a.rendered.placements[side]} for side in SIDES],
                "buttons": [{"side": side, "rect": list(self.layout.buttons[side])} for side in SIDES]}
            if self.config.kind == "haptic":
                ident = self.identities[self.config.reference][t.garment]["manifest_sha256"][:12]
                trial["visual"] = f"/api/study/visual/{t.garment}.png?v={ident}"
            else:
                for p in trial["panels"]:
                    p["image"] = f"/api/study/image/{a.token}/{p['side']}.png"
            return {"state": "trial", "trial": trial}

    def _time_left(self, a: _Active) -> float | None:
        if a.deadline is None:
            return None
        return max(0.0, a.deadline - time.monotonic())

    # -- the participant's answers -------------------------------------------------------------------------------
    def _stage_token(self, stage: str, token: object) -> _Active | None:
        a = self._active
        if a is None or a.stage != stage or token != a.token:
            return None
        return a

    def consent(self, token: object, agreed: object, version: object) -> dict:
        if not isinstance(agreed, bool):
            raise InputError("agreed must be true or false")
        with self._lock:
            a = self._stage_token("consent", token)
            if a is None:
                return self._ignore("stale_consent", detail="not the current consent screen")
            c = self.config.consent
            assert c is not None
            if version != c.version:
                return self._ignore("stale_consent", detail="the page showed another consent version")
            self.log.append("consent", participant=a.key[0], session=a.key[1], agreed=agreed, version=c.version,
                            text_sha256=c.sha256, **self.log.stamp())
            if not agreed:
                self.log.append("end", participant=a.key[0], session=a.key[1], reason="no_consent",
                                **self.log.stamp())
                self._finish(a.key, NOTICES["no_consent"])
            else:
                self._advance()
            return {"recorded": True, "agreed": agreed}

    def demographics(self, token: object, answers: object) -> dict:
        fields = self.config.demographics or {}
        if not isinstance(answers, dict):
            raise InputError("answers must be an object field -> choice")
        unknown = sorted(str(k) for k in answers if k not in fields)
        if unknown:
            raise InputError(f"unknown demographics field(s): {', '.join(unknown)[:200]}")
        clean: dict[str, str | None] = {}
        for name, choices in fields.items():
            v = answers.get(name)
            if v is not None and v not in choices:
                raise InputError(f"{name} must be one of the offered choices (or left unanswered)")
            clean[name] = v
        with self._lock:
            a = self._stage_token("demographics", token)
            if a is None:
                return self._ignore("stale_demographics")
            self.log.append("demographics", participant=a.key[0], session=a.key[1], answers=clean,
                            **self.log.stamp())
            self._advance()
            return {"recorded": True}

    def familiarised(self, token: object) -> dict:
        """The participant has felt this texture and goes on to the next one."""
        with self._lock:
            a = self._stage_token("familiarisation", token)
            if a is None:
                return self._ignore("stale_familiarisation")
            self.log.append("familiarisation", participant=a.key[0], session=a.key[1], step=a.step, action="done",
                            **self.log.stamp())
            self._advance()
            return {"recorded": True}

    def shown(self, token: object, page: object = None) -> dict:
        if page is not None and not (isinstance(page, str) and 0 < len(page) <= 64):
            raise InputError("page must be a short string naming the page instance")
        with self._lock:
            a = self._active
            if a is None or a.stage != "trial" or token != a.token or a.trial is None:
                return {"ok": False, "ignored": "not the current trial"}
            if a.shown is None or (page is not None and page != a.page):
                # A reloaded page shows the trial anew: the response time counts from this page's report.
                rec = self.log.append("shown", participant=a.key[0], session=a.key[1], trial=a.trial.index,
                                      token=a.token, page=page, reshown=a.shown is not None, **self.log.stamp())
                limit = self._time_limit(a.trial)
                if a.shown is None and limit is not None:
                    a.deadline = rec["mono"] + limit
                a.shown, a.page = rec, page
            return {"ok": True, "time_left_s": self._time_left(a)}

    def choose(self, token: object, side: object) -> dict:
        """A participant's tap. Returns {"recorded": True, ...} only after the response is durable."""
        if side not in SIDES:
            raise InputError("side must be 'left' or 'right'")
        if not isinstance(token, str) or not 0 < len(token) <= 64:
            raise InputError("token must be the trial's token (a short string)")
        with self._lock:
            a = self._active
            if a is None or a.stage != "trial" or token != a.token:
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
                    time_limit_s=self._time_limit(a.trial), bundles=self.identities,
                    software=self.log.software, shown=a.shown, stamp=now))
            except DuplicateResponse:
                return self._ignore("double_tap", participant=a.key[0], session=a.key[1], trial=a.trial.index,
                                    side=side)
            self._remember(a.token, a.key, a.trial.index, "answered")
            try:
                self._advance()
            except StudyLogWriteError as exc:   # the choice is durable; only what follows it waits for space
                self._log_down(exc)
            return {"recorded": True, "trial": rec["trial"], "side": side, "seq": rec["seq"]}

    def check_timeout(self) -> None:
        with self._lock:
            a = self._active
            if a is None or self._outage is not None:
                return
            now = time.monotonic()
            if a.stage == "trial" and a.deadline is not None and now >= a.deadline:
                self._record_timeout(a)
            elif a.stage == "timeout" and a.notice_until is not None and now >= a.notice_until:
                self._advance()

    def _record_timeout(self, a: _Active) -> None:
        assert a.trial is not None and a.shown is not None
        try:
            self.log.record_response(**response_payload(
                a.schedule, a.trial, choice=None, timeout=True, rt_s=None, time_limit_s=self._time_limit(a.trial),
                bundles=self.identities, software=self.log.software, shown=a.shown, stamp=self.log.stamp()))
        except DuplicateResponse:
            pass
        if a.token is not None:
            self._remember(a.token, a.key, a.trial.index, "timeout")
        if self.config.timeout_notice_s > 0:
            # Tell the participant plainly before moving on; the timer advances when the notice has been up.
            a.stage, a.token, a.deadline = "timeout", None, None
            a.notice_until = time.monotonic() + self.config.timeout_notice_s
            self._safe_clear()
        else:
            self._advance()

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
            log.warning("clearing the haptic device: %s", exc)

    # -- the page's API and the operator's control ops (mounted by kiosk.study.runtime) ---------------------------
    def http_get(self, req: "Request") -> "Response":
        from kiosk.service.server import Response

        if req.path == "/api/study/trial":
            return Response.json(self.page_state())
        if req.path == "/api/study/operator":
            _loopback_only(req)
            return Response.json(self.status(counts=req.arg("counts") in ("1", "true")))
        m = _VISUAL_RE.fullmatch(req.path)
        if m and m.group(1) in self.config.garments and self.config.kind == "haptic":
            path = self.bundles.visual_file(m.group(1))
            ctype = _IMAGE_TYPES.get(path.suffix.lower(), "application/octet-stream")
            return Response(200, path.read_bytes(), ctype, {"Cache-Control": "private, max-age=3600"})
        m = _IMAGE_RE.fullmatch(req.path)
        if m:
            with self._lock:
                a = self._active
                if a is not None and a.token == m.group(1) and a.rendered is not None \
                        and m.group(2) in a.rendered.images:
                    return Response(200, a.rendered.images[m.group(2)], "image/png",
                                    {"Cache-Control": "private, max-age=600"})
        m = _TEXTURE_RE.fullmatch(req.path)
        if m:
            with self._lock:
                a = self._active
                if a is not None and a.token == m.group(1) and a.texture_png is not None:
                    return Response(200, a.texture_png, "image/png", {"Cache-Control": "no-store"})
        return Response.error(404, f"nothing at {req.path}")

    def http_post(self, req: "Request") -> "Response":
        from kiosk.service.server import Response

        body = req.json()
        if not isinstance(body, dict):
            raise InputError("the request body must be a JSON object")
        if req.path in _PARTICIPANT_POSTS:
            unavailable = Response.json({"recorded": False, "error": "the study log cannot be written; nothing was "
                                         "recorded", "notice": CALL_RESEARCHER}, 503)
            if self._outage is not None:
                return unavailable
            try:
                return self._participant_post(req.path, body)
            except StudyLogWriteError as exc:
                with self._lock:
                    self._log_down(exc)
                return unavailable
        if req.path in ("/api/study/release", "/api/study/operator/next"):
            _loopback_only(req)
            _only(body, set())
            try:
                return Response.json({"ok": True, **self.release(by="key" if req.path.endswith("release")
                                                                  else "operator page")})
            except StudyLogWriteError as exc:
                with self._lock:
                    self._log_down(exc)
                return Response.json({"ok": False, "error": str(exc)})
            except StudyError as exc:
                return Response.json({"ok": False, "error": str(exc)})
        return Response.error(404, f"nothing at {req.path}")

    def _participant_post(self, path: str, body: dict) -> "Response":
        from kiosk.service.server import Response

        if path == "/api/study/shown":
            _only(body, {"token", "page"})
            return Response.json(self.shown(body.get("token"), body.get("page")))
        if path == "/api/study/choice":
            _only(body, {"token", "side", "page"})
            return Response.json(self.choose(body.get("token"), body.get("side")))
        if path == "/api/study/consent":
            _only(body, {"token", "agreed", "version"})
            return Response.json(self.consent(body.get("token"), body.get("agreed"), body.get("version")))
        if path == "/api/study/demographics":
            _only(body, {"token", "answers"})
            return Response.json(self.demographics(body.get("token"), body.get("answers")))
        if path == "/api/study/familiarised":
            _only(body, {"token"})
            return Response.json(self.familiarised(body.get("token")))
        raise AssertionError(f"not a participant request: {path}")

    def control(self, request: dict) -> dict:
        """Control-socket ops: study.start {participant, new_session}, study.status {counts}, study.stop,
        study.next, study.skip, study.withdraw {participant}."""
        op = request.get("op")
        try:
            if op == "study.start":
                return {"ok": True, **self.start(request.get("participant"),
                                                 new_session=bool(request.get("new_session", False)))}
            if op == "study.status":
                return {"ok": True, **self.status(counts=bool(request.get("counts", False)))}
            if op == "study.stop":
                return {"ok": True, **self.stop()}
            if op == "study.next":
                return {"ok": True, **self.release(by="operator")}
            if op == "study.skip":
                return {"ok": True, **self.skip_familiarisation()}
            if op == "study.withdraw":
                return {"ok": True, **self.withdraw(request.get("participant"))}
        except StudyLogWriteError as exc:
            with self._lock:
                self._log_down(exc)
            return {"ok": False, "error": str(exc)}
        except KioskError as exc:
            return {"ok": False, "error": str(exc)}
        return {"ok": False, "error": f"unknown study op {op!r} (study.start, study.status, study.stop, study.next, "
                                     "study.skip, study.withdraw)"}


_PARTICIPANT_POSTS = ("/api/study/shown", "/api/study/choice", "/api/study/consent", "/api/study/demographics",
                      "/api/study/familiarised")
_VISUAL_RE = re.compile(r"/api/study/visual/([a-z0-9][a-z0-9._-]{0,63})\.png")
_IMAGE_RE = re.compile(r"/api/study/image/([0-9a-z-]{1,64})/(left|right)\.png")
_TEXTURE_RE = re.compile(r"/api/study/texture/([0-9a-z-]{1,64})\.png")
_IMAGE_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".webp": "image/webp"}


def trial_scene(config: StudyConfig, bundles: StudyBundles, layout: Layout, trial: Trial) -> Scene:
    """Haptic: reference visual on both halves (no visual inference), tactile from each side's condition, the same
    half. Visual: each side's visual output from the reference sketch, whole garment, no tactile."""
    haptic = config.kind == "haptic"
    panels = tuple(Panel(id=side, rect=layout.panels[side],
                         bundle=bundles.get(trial.condition_on(side), trial.garment).key,
                         visual="reference" if haptic else "model", tactile="model" if haptic else "none",
                         sketch="reference", half=trial.half)
                   for side in SIDES)
    return Scene(panels=panels, screen=layout.screen)


def _practice_hint(untimed: bool) -> str:
    """One short line under the question during practice (the full instructions were on the screen before)."""
    return "Practice pair: it is not counted" + (" and not timed." if untimed else ".")


def _png(pixels: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", pixels)
    if not ok:
        raise ValueError("PNG encoding failed")
    return buf.tobytes()


def _loopback_only(req: "Request") -> None:
    from kiosk.service.config import is_loopback

    if not is_loopback(req.client):
        raise InputError("the operator side answers on the kiosk itself (loopback) only")


def _only(body: dict, allowed: set[str]) -> None:
    extra = sorted(str(k) for k in body if k not in allowed)
    if extra:
        raise InputError(f"unknown field(s): {', '.join(extra)}")
