"""Robot model math shared by every stage: forward kinematics, procedure geometry, PTP profiles."""
