#!/bin/sh
# Stands in for a Python whose Dr.Jit hits an unusable LLVM: it aborts (SIGABRT).
kill -ABRT $$
