"""Jobs: one function per command. Files in, files out; they call the library and the report."""
