"""Stage 1, the map: fit a model toward the prediction, project it, certify it.

`models` (moments and the model ladder) and `kernels`, `projection`, `certificate`
(the one certification gate, `certify_map`), `step` (one step's certified map) and
`auto` (the collision-aware choice among candidate maps). Imports only `penfree.core`
base modules (`topology`, `polynomial`).
"""
