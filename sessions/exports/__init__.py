"""What leaves the system for other tools and for paper: a session's FIT activity file
(:mod:`.fit`) and its one-page PDF report (:mod:`.report`), both built from plain data
(:mod:`.data`: the telemetry columns, the protocol's phases). CSV export lives with the store
(:meth:`sessions.store.timeseries.TelemetryRepository.export_csv`). See ``docs/exports.md``."""
