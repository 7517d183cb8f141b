"""User-facing errors: one line, naming the file or field at fault."""


class BenchError(Exception):
    """An error the user can fix (bad file, bad field, bad value). Printed as one line by the CLI."""


class ConfigError(BenchError):
    """A malformed model, scenario or dataset file: names the file and the field."""

    def __init__(self, source: str, field: str, problem: str):
        self.source, self.field, self.problem = str(source), field, problem
        super().__init__(f"{source}: {field}: {problem}")
