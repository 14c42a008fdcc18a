"""Session protocols: the phases a session runs (warm-up, seek, train, profile, cool-down),
their validated configuration (:mod:`.config`), what each phase does stretch by stretch
(:mod:`.plan`), the loop's reference generator that runs them (:mod:`.runner`), the cues a
person follows (:mod:`.cues`) and what each phase produced (:mod:`.analysis`)."""
