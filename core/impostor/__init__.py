"""The impostor and its stored forms: the impostor and its payload kinds (``impostor``), the bundle
folder (``bundle``), its GLB (``glb``, ``glb_compression``) and a job's impostor database (``database``)."""
