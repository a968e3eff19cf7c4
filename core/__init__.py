"""The science of model-based motion capture, with no web and no database.

Kinematic model (``model``), camera rig (``rig``), joint-angle histograms
(``histogram``, Eq. 4), the Eq. 5 error (``error``), Simulated Annealing
(``anneal``, Eq. 6) with local refinement (``refine``), per-image and
per-sequence fitting (``fit``) and a synthetic renderer (``synth``).
"""
