"""Layered depth images (seed 004 §4; Shade et al. 1998), shared by point-based and LDI impostors: the
image (``image``), its construction from nine images (``construction``), its warp (``warp``) and its
atlas pages (``pages``)."""
