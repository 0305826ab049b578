-- an empty message with no position: an empty line on stderr
error("", 0)
