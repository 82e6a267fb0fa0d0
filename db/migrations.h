/* migrations.h: the schema migrations embedded from db/migrations/ at build
 * time (db/embed.cmake). Migration i brings the schema to version i + 1. */
#ifndef CVRE_MIGRATIONS_H
#define CVRE_MIGRATIONS_H

struct db_migration {
    const char *name; /* file name, e.g. "0001_sessions.sql" */
    const char *sql;
};

extern const struct db_migration db_migrations[];
extern const int db_migration_count;

#endif
