"""What a person or another tool reads: report, history, live progress."""
