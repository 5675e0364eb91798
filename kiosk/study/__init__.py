"""The A/B haptic user study (paper Sec. 5 and supplement): config, schedules, the crash-safe log, the service that
runs trials through the kiosk daemon, and the statistics researchers publish.

Nothing here imports torch; the report imports matplotlib only when a plot is asked for.
"""
