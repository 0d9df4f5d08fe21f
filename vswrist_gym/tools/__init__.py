"""Tools around the environments that are not environments: benchmarks, probes, tables, videos, the viewer,
task pictures, soak and closure checks, the paper's reproduction, ``vswrist info``. Each is
``python -m vswrist_gym.tools.<name>`` and most are ``vswrist`` subcommands."""
