"""Accessibility checks every page's test runs on what the browser shows."""

from __future__ import annotations

from playwright.sync_api import Page

UNLABELLED_CONTROLS = """
() => {
  const text = (id) => document.getElementById(id)?.textContent || "";
  const nameOf = (el) =>
    (el.labels && el.labels.length ? [...el.labels].map((l) => l.textContent).join(" ") : "")
    || el.getAttribute("aria-label")
    || (el.getAttribute("aria-labelledby") || "").split(/\\s+/).map(text).join(" ")
    || (["BUTTON", "A"].includes(el.tagName) ? el.textContent : "")
    || el.getAttribute("title")
    || "";
  return [...document.querySelectorAll("input, select, textarea, button, a[href]")]
    .filter((el) => el.getClientRects().length > 0 && el.type !== "hidden")
    .filter((el) => !nameOf(el).trim() || el.tabIndex < 0)
    .map((el) => el.outerHTML.slice(0, 120));
}
"""


def assert_controls_labelled(page: Page) -> None:
    """Every visible control has a name a screen reader reads and is reachable with Tab."""
    unlabelled = page.evaluate(UNLABELLED_CONTROLS)
    assert not unlabelled, f"controls without a label or out of the tab order: {unlabelled}"
