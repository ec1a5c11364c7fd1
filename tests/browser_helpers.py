"""Debian's chromium for the browser tests (Playwright drives it; `npx playwright install` is not
used: CI installs the Debian package, scripts/install.sh --test)."""

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--no-first-run", "--disable-quic", "--disable-extensions",
                 "--disable-default-apps", "--no-default-browser-check", "--metrics-recording-only"]
