"""Parabolic-trough facet alignment by the theoretical-overlay photographic method (Ren et al. 2014).

``geometry`` (B/E edges, eqs 1–10, vectorised and bracketed), ``paper`` (the paper's own equations
and the boresight gauge, eq. 11), ``camera`` (pinhole), ``config`` (COLLECTOR.yaml, CAMERA.yaml),
``overlay`` (theoretical edges in the image), ``measure`` (edge detection and tilts), ``render``
(independent ray-traced photos), ``draw`` and ``results`` (overlay PNG, JSON). See docs/trough.md.
"""
