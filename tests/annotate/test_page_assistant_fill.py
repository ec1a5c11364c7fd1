"""Y (the assistant's confident proposals) in the real browser: a bulk decision fills what no decision
reached yet (annotate/static/app.js, ``fillEntry``): a pixel the person already decided inside a group the
assistant then takes keeps the person's decision, and one undo takes the whole of Y back."""

from __future__ import annotations

import pytest
from annotate_helpers import ServerProcess, close_page, open_page, wait_until, write_review_log

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    d = tmp_path_factory.mktemp("assistfill")
    log = d / "review.mcap"
    write_review_log(log, frames=3, shape=(480, 640))
    # gate 0: two labelled frames (one held out at a time) are enough for the page to pre-fill
    srv = ServerProcess(log, d / "labels.sqlite", annotator="alice", extra=("--assistant-gate", "0"))
    yield srv
    srv.stop()


def _label_frame(page, index: int) -> None:
    """Frame ``index``: the groups standing more than 1 mm off their surface are outliers, the rest not (both
    classes, so the assistant can train); Enter marks it reviewed and opens the next frame."""
    wait_until(page, f"window.zcut.state().index === {index}")
    rows = page.evaluate("window.zcut.entries()")
    groups = [(k, r) for k, r in enumerate(rows) if r["src"] == "g"]
    assert any((r["gap"] or 0) > 1 for _, r in groups) and any((r["gap"] or 0) <= 1 for _, r in groups), rows
    for _, r in groups:
        for _attempt in range(5):  # the list may be re-sorted when the assistant's proposals arrive: find it again
            k = next(i for i, e in enumerate(page.evaluate("window.zcut.entries()")) if e["src"] == "g" and e["id"] == r["id"])
            page.click(f"#candlist .cand[data-k='{k}']")
            try:
                wait_until(page, f"window.zcut.state().selected && window.zcut.state().selected.id === {r['id']}",
                           timeout_s=10)
                break
            except AssertionError:
                continue
        page.keyboard.press("a" if (r["gap"] or 0) > 1 else "r")
    page.keyboard.press("Enter")
    wait_until(page, f"window.zcut.state().index === {index + 1}")


def _a_pixel_of(page, group: dict) -> tuple[int, int]:
    """A valid pixel of review group ``group`` (the nearest to its centre)."""
    at = page.evaluate(f"""(() => {{
        const cx = {int(group['cx'])}, cy = {int(group['cy'])}, st = window.zcut.state();
        for (let r = 0; r < 60; r++) for (let y = cy - r; y <= cy + r; y++) for (let x = cx - r; x <= cx + r; x++) {{
          if (x < 0 || y < 0 || x >= st.W || y >= st.H) continue;
          const p = window.zcut.pixelState(x, y);
          if (p.group === {group['id']} && p.valid) return [x, y];
        }}
        return null; }})()""")
    assert at is not None, group
    return int(at[0]), int(at[1])


def test_y_keeps_a_pixel_the_person_decided_inside_a_group_it_takes(served, browser):
    page, errors, blocked = open_page(browser, served.url, viewport=(1366, 768))
    try:
        _label_frame(page, 0)
        _label_frame(page, 1)
        # the retrained assistant's proposals for frame 2, pre-filled (gate 0), at least one outlier group
        try:
            wait_until(page, "(() => { const p = window.zcut.proposals(); return p && p.prefill && p.out.length > 0; })()",
                       timeout_s=120)
        except AssertionError:
            raise AssertionError((page.evaluate("window.zcut.proposals()"), page.evaluate("window.zcut.assistant"),
                                  page.evaluate("window.zcut.entries()"))) from None
        props = page.evaluate("window.zcut.proposals()")
        rows = {r["id"]: r for r in page.evaluate("window.zcut.entries()") if r["src"] == "g"}
        g = max((rows[i] for i in props["out"]), key=lambda r: r["n"])
        assert g["n"] >= 4 and g["state"] == "undecided", g
        x, y = _a_pixel_of(page, g)
        # the eraser, 1 px: the person says this one pixel of the group is no outlier (the group stays undecided)
        page.keyboard.press("e")
        page.evaluate("document.querySelector('#brushsize').value = 1; "
                      "document.querySelector('#brushsize').dispatchEvent(new Event('input'))")
        page.evaluate(f"window.zcut.look({x}, {y}, 8)")
        c = page.evaluate(f"window.zcut.imageToClient({x}, {y})")
        page.mouse.move(c["x"], c["y"])
        page.mouse.down()
        page.mouse.up()
        wait_until(page, f"window.zcut.pixelState({x}, {y}).R === 1")
        assert page.evaluate(f"window.zcut.pixelState({x}, {y})")["L"] == 0
        before = page.evaluate("window.zcut.state()")
        erased = page.evaluate("""(() => {  // the flat indices of the pixels the eraser decided
            const st = window.zcut.state(), got = [];
            for (let y = 0; y < st.H; y++) for (let x = 0; x < st.W; x++) {
              const p = window.zcut.pixelState(x, y);
              if (p.R === 1) got.push(y * st.W + x);
            }
            return got; })()""")
        assert before["nL"] == 0 and len(erased) == before["nR"] >= 1
        mine = next(r for r in page.evaluate("window.zcut.entries()") if r["src"] == "g" and r["id"] == g["id"])
        assert mine["state"] == "undecided" and mine["confident"]
        page.keyboard.press("y")
        wait_until(page, "window.zcut.state().nL > 0")
        after = page.evaluate("window.zcut.state()")
        took = next(r for r in page.evaluate("window.zcut.entries()") if r["src"] == "g" and r["id"] == g["id"])
        assert took["state"] == "accepted"
        # the person's pixel kept its decision; every other pixel of the taken outlier groups is labelled
        assert page.evaluate(f"window.zcut.pixelState({x}, {y})") == {"L": 0, "R": 1, "group": g["id"], "valid": 1}
        # every pixel of the taken outlier groups is labelled an outlier, but those the eraser decided before
        out_ids = list(props["out"])
        wrong = page.evaluate(f"""(() => {{
            const st = window.zcut.state(), out = new Set({out_ids}), erased = new Set({erased});
            let wrong = 0, kept = 0;
            for (let y = 0; y < st.H; y++) for (let x = 0; x < st.W; x++) {{
              const p = window.zcut.pixelState(x, y);
              if (!out.has(p.group) || !p.valid) continue;
              const i = y * st.W + x;
              if (erased.has(i)) {{ if (p.L === 0 && p.R === 1) kept++; else wrong++; }}
              else if (p.L !== 1) wrong++;
            }}
            return [wrong, kept]; }})()""")
        assert wrong[0] == 0 and wrong[1] >= 1, wrong
        assert after["nL"] == sum(rows[i]["n"] for i in out_ids) - wrong[1], (after["nL"], wrong)
        # one undo takes the whole of Y back, the person's pixel still decided
        page.keyboard.press("Control+z")
        wait_until(page, f"window.zcut.state().nL === {before['nL']}")
        assert page.evaluate(f"window.zcut.pixelState({x}, {y})")["R"] == 1
        assert page.evaluate("window.zcut.state()")["nR"] == before["nR"]
        assert not errors and not blocked
    finally:
        close_page(page)
