"""The export tests need no server, worker or device: real simulated sessions
(:mod:`testing.exports`) turned into FIT files and PDF reports, read back by independent
decoders (fitdecode, garmin-fit-sdk's decoder, pypdf)."""
