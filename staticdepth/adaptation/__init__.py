"""On-site adaptation as streamed, resumable stages (one module each, hloc-style).

predict -> agents -> pseudo_labels -> finetune -> (predict ft) -> ground_plane -> align -> scale.
Each stage is ``run(conf, ws, ...)`` on a :class:`~staticdepth.adaptation.common.Workspace` (the
sequence, its prediction store and the stage files in ``<SEQ>.h5.adapt/``); frames flow in
chunks, outputs are written frame by frame and carry the hash of the settings they depend on, so
a stage whose output is complete with the same hash is skipped and an interrupted one resumes.
:mod:`staticdepth.adapt` is the pipeline of stage calls.
"""
