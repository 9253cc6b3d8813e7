"""The numeric pipeline, one subpackage per stage (see ARCHITECTURE.md).

Base modules (`topology`, `describe`) are used by every stage. The stages are
`fit` -> `contact` -> `verify` -> `trust`; a stage imports only base modules and
the stages before it. `pipeline` wires them and nothing in `core` imports it.
"""
