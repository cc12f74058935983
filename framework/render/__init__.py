"""Mitsuba rendering of the scene model: the variant and libLLVM set-up (:mod:`.backend`), the
exact kernel-sum BSDF (:mod:`.kernel_bsdf`), per-variant Python plugins (:mod:`.plugin`),
environment map conventions (:mod:`.envmap`) and the one builder from a scene model and weights
ρ to a Mitsuba scene (:mod:`.mitsuba_scene`)."""
