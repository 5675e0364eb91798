"""The kiosk's `fleet:` config section (in kiosk.yaml, read by `vtkiosk fleet sync` and by the daemon's /healthz).

No `url`: the kiosk takes no part in a fleet (the daemon shows no fleet check, `fleet sync` refuses to run).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from kiosk.contract.errors import KioskError
from kiosk.fleet.layout import CHANNELS, KIOSK_ID_RE


class FleetConfigError(KioskError):
    pass


@dataclass(frozen=True)
class FleetConfig:
    """url: the repository's base URL (metadata/ and targets/ under it). root: the trust anchor, the root metadata
    from the key ceremony, provisioned with the kiosk (never fetched from the server). kiosk_id: this kiosk's name,
    whose hash decides its staged-rollout bucket. channel: canary or stable. state_dir: TUF metadata cache, downloads
    and the last sync's result. attempts/backoff_s: tries per sync when the repository does not answer, waiting
    backoff_s, 2x, 4x ... (capped at max_backoff_s) between them. stale_after_s: /healthz calls the metadata stale
    past this age (the kiosk keeps serving)."""

    url: str | None = None
    root: Path | None = None
    kiosk_id: str | None = None
    channel: str = "stable"
    state_dir: Path = Path("/var/lib/vtkiosk/fleet")
    attempts: int = 3
    backoff_s: float = 5.0
    max_backoff_s: float = 60.0
    timeout_s: float = 30.0
    stale_after_s: float = 86400.0

    def __post_init__(self) -> None:
        def need(cond: bool, msg: str) -> None:
            if not cond:
                raise FleetConfigError(msg)

        need(self.channel in CHANNELS, f"fleet.channel must be one of {', '.join(CHANNELS)}")
        need(1 <= self.attempts <= 10, "fleet.attempts must be from 1 to 10")
        need(0 <= self.backoff_s <= 3600 and 0 <= self.max_backoff_s <= 3600,
             "fleet.backoff_s and fleet.max_backoff_s must be from 0 to 3600 seconds")
        need(0 < self.timeout_s <= 600, "fleet.timeout_s must be > 0 and at most 600 seconds")
        need(self.stale_after_s > 0, "fleet.stale_after_s must be > 0 seconds")
        if self.url is not None:
            need(self.url.startswith(("http://", "https://")), "fleet.url must be an http:// or https:// URL")
            need(self.root is not None, "fleet.root (the trust anchor root.json) is required with fleet.url")
            need(self.kiosk_id is not None and bool(KIOSK_ID_RE.match(self.kiosk_id)),
                 "fleet.kiosk_id is required with fleet.url (1 to 128 letters, digits, '.', '_', ':', '-')")

    @property
    def enabled(self) -> bool:
        return self.url is not None
