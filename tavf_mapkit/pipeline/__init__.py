"""The build runner: a declared list of stages run into an atomic, incremental build folder.

- stages.py     the Stage interface and the ``@register_stage("name")`` registry
- context.py    what a running stage sees (build folder, artifacts, options, earlier stages' facts)
- config.py     pipeline files (pipelines/NAME.toml) and command-line overrides
- manifest.py   manifest.json: inputs with sha256, tool versions, per-stage fingerprints, timings, outputs
- buildfolder.py  staging next to the target, atomic swap, cleanup on failure, interrupt or SIGTERM
- runner.py     the loop: reuse unchanged stages, run the others, write the manifest, swap
- builtin/      the stages themselves; a new module there registers itself, the runner needs no change
"""
