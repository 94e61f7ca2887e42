"""How good an impostor is: its evaluation against the real geometry (``evaluation``), bundles side by
side (``comparison``), walkthroughs through an impostor database (``walkthrough``), and the deferred
shading that judges an impostor lit as three.js lights it (``lighting``, with three.js's ``dfg``
table)."""
