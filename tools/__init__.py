"""Workstation scripts (train, export, quantize, evaluate, bench), each a main(argv=None) -> int."""
