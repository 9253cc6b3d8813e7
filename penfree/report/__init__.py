"""Savings reports: building a file's report from the library (`build`; its
entry from per-step parts, whole or of frame ranges, `entry`), Markdown,
checks and plots. Calls `penfree.core`; no stage imports it.
"""
