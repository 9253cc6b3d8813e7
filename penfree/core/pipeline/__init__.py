"""The orchestration: the deform driver, per-component maps, the model ladder and the
sequence/file-level verification drivers. Only the CLI and `penfree.report` import it;
no stage does.
"""
