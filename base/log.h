/*
 * log.h: operator-readable logs on stderr, one line each:
 *   2026-11-22T10:04:05.123Z INFO  message
 * Thread-safe (each line is one write(2)). Lines over 1 KiB are truncated.
 */
#ifndef CVRE_LOG_H
#define CVRE_LOG_H

enum log_level { LOG_DEBUG = 0, LOG_INFO = 1, LOG_WARN = 2, LOG_ERROR = 3, LOG_OFF = 4 };

/* Lines below level are dropped. Default LOG_INFO. */
void log_set_level(int level);
int log_level(void);
/* Parses "debug", "info", "warn", "error" or "off"; -EINVAL if unknown. */
int log_parse_level(const char *name);

void log_msg(int level, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

#define log_debug(...) log_msg(LOG_DEBUG, __VA_ARGS__)
#define log_info(...) log_msg(LOG_INFO, __VA_ARGS__)
#define log_warn(...) log_msg(LOG_WARN, __VA_ARGS__)
#define log_error(...) log_msg(LOG_ERROR, __VA_ARGS__)

#endif
