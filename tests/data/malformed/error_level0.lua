-- error with level 0: a message with no position, printed as it is ("boom")
error("boom", 0)
