"""Savings reports: building a file's report from the library (`build`), Markdown,
checks and plots. Calls `penfree.core`; no stage imports it.
"""
