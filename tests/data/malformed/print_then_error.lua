-- print writes to stderr: a failing scenario that printed first leaves two lines there
print("debug: loading")
error("bad")
