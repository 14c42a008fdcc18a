"""Tooling for the tests, the benchmarks and the screenshots: not shipped in the wheel (only
``sessions``, ``server`` and ``webui`` are), and it assumes a checkout of the repository.

    live          scenarios and a follower for the live-machine tests (worker, ODrive, ring)
    server        a real ``ergoseek serve``/``demo`` in its own process, and its clients
    browser       headless Chromium (Playwright) on the dashboard of a real ``ergoseek demo``
    screenshot    ``python -m testing.screenshot``: docs/img/dashboard.png
    cli           ``ergoseek …`` run as a user runs it
    store         deterministic telemetry and a fast real password hasher
    store_writer  ``python -m testing.store_writer URL``: a session writer to kill
    postgres      a throwaway PostgreSQL cluster
    docker        a Docker engine of the suite's own, a base image made without a registry
    exports       simulated sessions, long ones tiled, for the export tests and benchmarks
    benchmarks    a benchmark script as a module (its simulated people), for the tests
"""
