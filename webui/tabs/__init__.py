"""The dashboard's tabs on the right: Live (machine status, E-STOP, session setup and control,
the event log), History (a user's sessions and optimum, any past session's charts and CSV) and,
for trainers, Users (add or edit a user and their simulated person)."""
