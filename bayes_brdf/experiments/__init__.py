"""The paper's experiments, each reproducible from one function (and a CLI command)."""
