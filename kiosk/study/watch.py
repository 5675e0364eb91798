"""The researcher's live view as text (`vtkiosk study status --watch`); the page /study-operator shows the same.

Read-only: it asks the running study for its status and draws it. Running preference counts stay hidden unless the
researcher asks for them (`--counts`), so nobody peeks at the outcome by accident while a study runs.
"""
from __future__ import annotations

STAGES = {"consent": "reading the consent text", "demographics": "answering the optional questions",
          "familiarisation": "feeling the familiarisation textures", "wait": "waiting for you to release the next trial",
          "trial": "exploring a trial", "timeout": "being told the time ran out"}


def format_status(st: dict) -> str:
    """One screen of text from a `study.status` reply."""
    lines = [f"{st.get('kind', 'haptic')} study {st['study_id']}: {st['sessions']} session(s), "
             f"{st['responses']} response(s) logged; done: {', '.join(st.get('participants_done') or []) or '-'}"]
    if st.get("withdrawn"):
        lines.append(f"withdrawn (left out of the report): {', '.join(st['withdrawn'])}")
    a = st.get("active")
    if a is None:
        fin = st.get("finished")
        lines.append("no session running" + (f" (last: {fin['participant']} session {fin['session']} finished)"
                                             if fin else ""))
    else:
        lines.append(f"participant {a['participant']} session {a['session']}: {STAGES.get(a['stage'], a['stage'])}")
        lines.append(f"  progress: {a['test_answered']}/{a['test_trials']} test trials, {a['answered']}/{a['trials']} "
                     "trials in all")
        if a.get("familiarisation"):
            f = a["familiarisation"]
            lines.append(f"  familiarisation texture {f['step']}/{f['of']}: {f['texture']} "
                         "(skip: vtkiosk study skip)")
        if a.get("put_garment_on_table"):
            lines.append(f"  garment on the table: {a['put_garment_on_table']} "
                         f"(trial {a['trial']}, {a['block']}, vs {a['comparison']})")
        if a.get("waiting_for_release"):
            lines.append("  >> release the trial: vtkiosk study next (or the button on /study-operator)")
        if a.get("time_left_s") is not None:
            lines.append(f"  time left: {a['time_left_s']:.0f} s")
        if a.get("error"):
            lines.append(f"  PROBLEM: {a['error']}")
    counts = st.get("counts")
    if counts is None:
        lines.append("preference counts: hidden (add --counts to show them)")
    else:
        lines.append("preference counts (test trials, withdrawn left out):")
        for c in counts:
            lines.append(f"  {c['reference']} vs {c['comparison']:<16} {c['prefer_reference']:>3}/{c['n']:<3}"
                         f" timeouts {c['timeouts']}")
    return "\n".join(lines)
