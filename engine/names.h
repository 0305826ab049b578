/* Names that end up in CSV headers (trajectory.csv's marker columns), JSON and log lines:
 * targets, markers, obstacles, regions and materials. A name is 1 to NS_LIMIT_NAME_LENGTH bytes
 * (sim/ns_limits.h) of printable ASCII (0x20-0x7e: spaces are fine) without ',', '"' or '\'.
 * scripts/needlesim.lua refuses other names where a scenario gives them, with its file and
 * line; this checks them again where the engine reads them (a scenario may have replaced the
 * module's checks). */
#ifndef NS_NAMES_H
#define NS_NAMES_H

/* The rule, as messages state it. */
#define NS_NAME_RULE "1 to 64 bytes of printable ASCII without ',', '\"' or '\\' (spaces are fine)"

/* 0 when name follows the rule; else -1 with what is wrong in why ("byte 3 is 0x0a"). */
int ns_name_check(const char *name, char *why, int why_sz);

/* Makes a message one line for the terminal: control characters (a newline a scenario put in a
 * string the message quotes) become spaces. */
void ns_one_line(char *s);

#endif
