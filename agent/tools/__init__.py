"""The tool library (named tools per robot) and the commands that read and change it."""
