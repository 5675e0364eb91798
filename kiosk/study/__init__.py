"""User studies (paper Sec. 5 and supplement), haptic and visual A/B: config, schedules, the crash-safe log, the
service that runs sessions through the kiosk daemon (consent, optional questions, familiarisation, the operator's
release between trials), the researcher's live view, study planning, the exported web page for remote visual
studies, and the statistics researchers publish.

Nothing here imports torch; the report imports matplotlib only when a plot is asked for.
"""
