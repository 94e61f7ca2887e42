"""How good an impostor is: its evaluation against the real geometry (``evaluation``), bundles side by
side (``comparison``) and walkthroughs through an impostor database (``walkthrough``)."""
