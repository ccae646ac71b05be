"""homofac.io."""
