using System;
using System.Collections.Generic;
using System.Globalization;

namespace Vista.Client
{
    /// <summary>
    /// Typed reads of the members of a parsed JSON object (see <see cref="Json"/>). A required
    /// member that is missing or of the wrong kind throws <see cref="FormatException"/> naming it.
    /// </summary>
    public static class JsonFields
    {
        /// <summary>A string member; null when it is absent or null.</summary>
        public static string GetString(this IDictionary<string, object> json, string name)
        {
            object value = Raw(json, name);
            if (value == null || value is string)
            {
                return (string)value;
            }
            throw WrongKind(name, "a string");
        }

        /// <summary>A required string member.</summary>
        public static string GetRequiredString(this IDictionary<string, object> json, string name)
        {
            return Required(GetString(json, name), name);
        }

        /// <summary>A required integer member.</summary>
        public static long GetInt64(this IDictionary<string, object> json, string name)
        {
            return Required(GetNullableInt64(json, name), name).Value;
        }

        /// <summary>An integer member; null when it is absent or null.</summary>
        public static long? GetNullableInt64(this IDictionary<string, object> json, string name)
        {
            object value = Raw(json, name);
            if (value == null)
            {
                return null;
            }
            if (value is long)
            {
                return (long)value;
            }
            throw WrongKind(name, "an integer");
        }

        /// <summary>A required number member.</summary>
        public static double GetDouble(this IDictionary<string, object> json, string name)
        {
            return Required(GetNullableDouble(json, name), name).Value;
        }

        /// <summary>A number member; null when it is absent or null.</summary>
        public static double? GetNullableDouble(this IDictionary<string, object> json, string name)
        {
            object value = Raw(json, name);
            if (value == null)
            {
                return null;
            }
            double? number = AsDouble(value);
            if (number == null)
            {
                throw WrongKind(name, "a number");
            }
            return number;
        }

        /// <summary>A boolean member; <paramref name="fallback"/> when it is absent or null.</summary>
        public static bool GetBoolean(this IDictionary<string, object> json, string name, bool fallback)
        {
            object value = Raw(json, name);
            if (value == null)
            {
                return fallback;
            }
            if (value is bool)
            {
                return (bool)value;
            }
            throw WrongKind(name, "true or false");
        }

        /// <summary>An object member; null when it is absent or null.</summary>
        public static Dictionary<string, object> GetObject(this IDictionary<string, object> json, string name)
        {
            object value = Raw(json, name);
            if (value == null || value is Dictionary<string, object>)
            {
                return (Dictionary<string, object>)value;
            }
            throw WrongKind(name, "an object");
        }

        /// <summary>An array member; empty when it is absent or null.</summary>
        public static List<object> GetArray(this IDictionary<string, object> json, string name)
        {
            object value = Raw(json, name);
            if (value == null)
            {
                return new List<object>();
            }
            if (value is List<object>)
            {
                return (List<object>)value;
            }
            throw WrongKind(name, "an array");
        }

        /// <summary>The objects of an array member (empty when it is absent).</summary>
        public static List<Dictionary<string, object>> GetObjects(this IDictionary<string, object> json, string name)
        {
            var objects = new List<Dictionary<string, object>>();
            foreach (object item in GetArray(json, name))
            {
                var member = item as Dictionary<string, object>;
                if (member == null)
                {
                    throw WrongKind(name, "an array of objects");
                }
                objects.Add(member);
            }
            return objects;
        }

        /// <summary>An array of numbers; null when it is absent or null.</summary>
        public static double[] GetDoubles(this IDictionary<string, object> json, string name)
        {
            if (Raw(json, name) == null)
            {
                return null;
            }
            return AsDoubles(GetArray(json, name), name);
        }

        /// <summary>A parsed JSON array of numbers as doubles; <paramref name="name"/> names it
        /// in the error when it is something else.</summary>
        public static double[] AsDoubles(object value, string name)
        {
            var items = value as List<object>;
            if (items == null)
            {
                throw WrongKind(name, "an array of numbers");
            }
            var numbers = new double[items.Count];
            for (int i = 0; i < items.Count; i++)
            {
                double? number = AsDouble(items[i]);
                if (number == null)
                {
                    throw WrongKind(name, "an array of numbers");
                }
                numbers[i] = number.Value;
            }
            return numbers;
        }

        /// <summary>An object of integers (e.g. vote counts); empty when it is absent.</summary>
        public static Dictionary<string, int> GetCounts(this IDictionary<string, object> json, string name)
        {
            var counts = new Dictionary<string, int>();
            Dictionary<string, object> members = GetObject(json, name);
            if (members == null)
            {
                return counts;
            }
            foreach (KeyValuePair<string, object> member in members)
            {
                if (!(member.Value is long))
                {
                    throw WrongKind(name + "." + member.Key, "an integer");
                }
                counts[member.Key] = checked((int)(long)member.Value);
            }
            return counts;
        }

        static object Raw(IDictionary<string, object> json, string name)
        {
            object value;
            return json.TryGetValue(name, out value) ? value : null;
        }

        static double? AsDouble(object value)
        {
            if (value is double)
            {
                return (double)value;
            }
            if (value is long)
            {
                return Convert.ToDouble((long)value, CultureInfo.InvariantCulture);
            }
            return null;
        }

        static T Required<T>(T value, string name)
        {
            if (value == null)
            {
                throw new FormatException("JSON: the member '" + name + "' is missing");
            }
            return value;
        }

        static FormatException WrongKind(string name, string kind)
        {
            return new FormatException("JSON: the member '" + name + "' is not " + kind);
        }
    }
}
